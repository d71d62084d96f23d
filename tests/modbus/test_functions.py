"""Which requests the Modbus server answers (Modbus Application Protocol V1.1b3, docs/modbus.md):
function codes it does not implement are exception 01, 80..FF (exception-response codes,
not requests) too, quantities outside the specification's ranges 03; Read Device
Identification names grasplink. Checked on the request bytes (sans-IO), then on the wire
with raw requests (what no client library sends) and with a pymodbus client."""

from __future__ import annotations

import socket
import struct

import pytest
from pymodbus.client import ModbusTcpClient

from grasplink import __version__
from grasplink.gateway.config import parse_config
from grasplink.gateway.edge import GatewayEdge
from grasplink.gateway.service import Gateway
from grasplink.surfaces.modbus.functions import CODES, check_request
from grasplink.surfaces.modbus.registers import MAP_VERSION
from grasplink.surfaces.modbus.server import ModbusServer

UNSUPPORTED = (0x01, 0x02, 0x05, 0x07, 0x08, 0x0B, 0x0C, 0x0F, 0x11, 0x14, 0x15, 0x16, 0x18, 0x41)
READ_COUNTS_REFUSED = (0, 126, 65535)


def read(code: int, count: int, address: int = 0) -> bytes:
    return struct.pack(">BHH", code, address, count)


def write_multiple(count: int, data_words: int | None = None, byte_count: int | None = None):
    words = count if data_words is None else data_words
    size = 2 * count if byte_count is None else byte_count
    return struct.pack(">BHHB", 0x10, 0, count, size & 0xFF) + b"\x00\x01" * words


def read_write(read_count: int, write_count: int) -> bytes:
    head = struct.pack(">BHHHHB", 0x17, 0, read_count, 0, write_count, (2 * write_count) & 0xFF)
    return head + b"\x00\x01" * write_count


# -- the check, on bytes -------------------------------------------------------------------


@pytest.mark.parametrize("code", [*UNSUPPORTED, 0x00, 0x80, 0x81, 0x83, 0x90, 0xFF])
def test_a_function_code_not_implemented_or_an_exception_code_is_illegal_function(code):
    error = check_request(bytes([code]) + b"\x00\x00\x00\x01")
    assert error is not None and error.code == 0x01
    assert f"0x{code:02X}" in str(error)
    if code & 0x80:
        assert "exception-response code" in str(error)


@pytest.mark.parametrize("code", [0x03, 0x04])
@pytest.mark.parametrize("count", READ_COUNTS_REFUSED)
def test_a_read_of_0_or_more_than_125_registers_is_illegal_data_value(code, count):
    error = check_request(read(code, count))
    assert error is not None and error.code == 0x03 and f"quantity {count}" in str(error)
    assert check_request(read(code, 125)) is None and check_request(read(code, 1)) is None


@pytest.mark.parametrize(
    "pdu, says",
    [
        (write_multiple(0), "quantity 0 outside 1..123"),
        (write_multiple(124), "quantity 124 outside 1..123"),
        (write_multiple(2, byte_count=3), "byte count 3"),
        (write_multiple(2, data_words=1), "2 data bytes for 2 registers"),
        (read_write(0, 1), "read quantity 0 outside 1..125"),
        (read_write(126, 1), "read quantity 126"),
        (read_write(1, 122), "write quantity 122 outside 1..121"),
        (read(0x03, 1)[:3], "a request of 3 bytes (expected 5)"),
        (b"\x06\x00\x00\x00\x01\x00", "a request of 6 bytes (expected 5)"),
        (b"\x2b\x0e\x00\x00", "read code 0 outside 1..4"),
    ],
)
def test_a_quantity_or_length_outside_the_specification_is_illegal_data_value(pdu, says):
    error = check_request(pdu)
    assert error is not None and error.code == 0x03 and says in str(error)


def test_only_the_documented_functions_pass_and_2b_only_as_device_identification():
    assert {0x03, 0x04, 0x06, 0x10, 0x17, 0x2B} == CODES
    assert check_request(b"\x06\x00\x00\x00\x01") is None
    assert check_request(write_multiple(123)) is None
    assert check_request(read_write(125, 121)) is None
    assert check_request(b"\x2b\x0e\x01\x00") is None
    error = check_request(b"\x2b\x0d\x00\x00")  # CANopen General Reference
    assert error is not None and error.code == 0x01 and "MEI type 0x0D" in str(error)


# -- on the wire ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def server():
    """A gateway nobody runs (no snapshot: reads answer the sentinels), served on a free port."""
    gateway = GatewayEdge(Gateway(parse_config({}, "<functions>")))
    with ModbusServer(gateway, "tcp://127.0.0.1:0", command_timeout_s=0.3) as served:
        yield served


def raw(server: ModbusServer, pdu: bytes, unit: int = 1) -> bytes:
    """One Modbus TCP request, its response PDU (an answer is required: 3 s timeout)."""
    with socket.create_connection(("127.0.0.1", server.address.port), timeout=3) as sock:
        sock.sendall(struct.pack(">HHHB", 0x1234, 0, len(pdu) + 1, unit) + pdu)
        head = b""
        while len(head) < 7:
            head += sock.recv(7 - len(head))
        tid, _, length, answered_unit = struct.unpack(">HHHB", head)
        assert (tid, answered_unit) == (0x1234, unit)
        body = b""
        while len(body) < length - 1:
            body += sock.recv(length - 1 - len(body))
        return body


@pytest.mark.slow
@pytest.mark.parametrize("code", UNSUPPORTED)
def test_the_server_answers_functions_it_does_not_implement_with_exception_01(server, code):
    # pymodbus alone answered 07, 08, 0B, 0C, 11 (as "Pymodbus"), 18 and 2B/0D
    assert raw(server, bytes([code]) + b"\x00\x00\x00\x01") == bytes([code | 0x80, 0x01])


@pytest.mark.slow
@pytest.mark.parametrize("code", [0x80, 0x81, 0x83, 0x84, 0x90, 0xFF])
def test_an_exception_response_code_sent_as_a_request_is_exception_01(server, code):
    # pymodbus alone answered 81..FF with 04 SERVER DEVICE FAILURE
    assert raw(server, bytes([code]) + b"\x00\x00\x00\x01") == bytes([code, 0x01])


@pytest.mark.slow
@pytest.mark.parametrize("code", [0x03, 0x04])
@pytest.mark.parametrize("count", READ_COUNTS_REFUSED)
def test_the_server_refuses_read_counts_outside_1_to_125_with_exception_03(server, code, count):
    # pymodbus alone answered 80 01 (function code 0, ILLEGAL FUNCTION)
    assert raw(server, read(code, count)) == bytes([code | 0x80, 0x03])


@pytest.mark.slow
def test_writes_with_bad_quantities_are_exception_03_and_good_requests_still_work(server):
    assert raw(server, write_multiple(124)) == b"\x90\x03"
    assert raw(server, read_write(126, 1)) == b"\x97\x03"
    version = MAP_VERSION.to_bytes(2, "big")
    assert raw(server, read(0x04, 1)) == b"\x04\x02" + version  # map_version
    assert raw(server, read(0x04, 1), unit=200) == b"\x04\x02" + version  # one gateway: any unit


@pytest.mark.slow
def test_a_pymodbus_client_gets_illegal_function_for_diagnostics_and_server_id(server):
    with ModbusTcpClient("127.0.0.1", port=server.address.port, timeout=3) as client:
        for response in (
            client.read_exception_status(),
            client.diag_query_data(b"\x12\x34"),
            client.diag_force_listen_only(no_response_expected=False),
            client.diag_get_comm_event_counter(),
            client.report_device_id(),
            client.read_fifo_queue(),
            client.mask_write_register(),
        ):
            assert response.isError() and response.exception_code == 0x01, response
        # not put in listen-only mode: it still answers
        assert client.read_input_registers(0, count=1).registers == [MAP_VERSION]


@pytest.mark.slow
def test_read_device_identification_names_grasplink_and_its_version(server):
    with ModbusTcpClient("127.0.0.1", port=server.address.port, timeout=3) as client:
        response = client.read_device_information()  # basic: objects 0..2
    assert not response.isError(), response
    assert response.information[0] == b"grasplink"
    assert response.information[1] == b"grasplink-gateway"
    assert response.information[2] == __version__.encode()
