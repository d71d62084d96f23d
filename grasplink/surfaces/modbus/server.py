"""The Modbus server: pymodbus at the edge of the register map, in its own thread and loop.

Nothing here touches the gateway's state or blocks its thread. Reads encode
`Gateway.latest` (the snapshot the gateway replaces whole at 20 Hz, read
without locks) and the gateway's current settings (`registers.settings_of`).
A write becomes one `Command` (`RegisterMap.command_for_write` checks address
and value first: a refused write posts nothing) posted to the gateway's mailbox
(its live edge, `gateway.edge.GatewayEdge`);
the reply waits, at most `command_timeout_s`, for the `CommandResult`:

- accepted: the normal reply;
- rejected by the gateway (no such node, a calibration it cannot use):
  exception 03 ILLEGAL DATA VALUE, and nothing changed;
- the edge's mailbox full: 06 SERVER DEVICE BUSY, nothing changed, try again;
- no result in time: 04 SERVER DEVICE FAILURE; the command stays queued
  and may still be applied: read the holding registers back.

Only pymodbus's documented server hooks (3.16, pinned):

- the datastore: a `SimDevice` per unit carries the tables, and its `action`, called
  before every access, fills the registers read or vetoes a write with an exception code;
- `custom_pdu`: request classes for every function code, registered with the server's
  decoder, put `functions.check_request` in front of pymodbus's own decoding: a function
  this server does not implement, or a quantity or length the specification does not
  allow, is answered with its exception code (01, 03), whatever pymodbus would do with it;
- `trace_pdu`: sees each decoded request first; a request to a unit no gateway has is
  answered 0x0B over TCP and dropped on a serial line, an exception-response code sent as
  a request is answered 01;
- `identity`: what Read Device Identification reports.

A process mastering several buses (`grasplink gateway --bus A --bus B`) has a gateway
per bus; one server serves them all, one unit id each (`units`): over TCP 1, 2, ...
in bus order, on a serial line the URL's unit and those after it. A request to a unit
id no gateway has is answered 0x0B GATEWAY TARGET DEVICE FAILED TO RESPOND over TCP, and
not at all on a serial line (another device's request).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import socket
import threading
from collections import Counter
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

from pymodbus import FramerType
from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusServerContext
from pymodbus.exceptions import NoSuchIdException
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.pdu.bit_message import (
    ReadCoilsRequest,
    ReadDiscreteInputsRequest,
    WriteMultipleCoilsRequest,
    WriteSingleCoilRequest,
)
from pymodbus.pdu.device import ModbusDeviceIdentification
from pymodbus.pdu.diag_message import DiagnosticBase
from pymodbus.pdu.file_message import (
    ReadFifoQueueRequest,
    ReadFileRecordRequest,
    WriteFileRecordRequest,
)
from pymodbus.pdu.mei_message import ReadDeviceInformationRequest
from pymodbus.pdu.other_message import (
    GetCommEventCounterRequest,
    GetCommEventLogRequest,
    ReadExceptionStatusRequest,
    ReportDeviceIdRequest,
)
from pymodbus.pdu.register_message import (
    MaskWriteRegisterRequest,
    ReadHoldingRegistersRequest,
    ReadInputRegistersRequest,
    ReadWriteMultipleRegistersRequest,
    WriteMultipleRegistersRequest,
    WriteSingleRegisterRequest,
)
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from grasplink.errors import BusError
from grasplink.gateway.commands import CommandResult
from grasplink.gateway.edge import FULL as MAILBOX_FULL
from grasplink.gateway.edge import GatewayEdge
from grasplink.surfaces.modbus.functions import CODES, IDENTIFICATION, check_request
from grasplink.surfaces.modbus.registers import (
    COMMAND_TIMEOUT_S,
    RegisterError,
    RegisterMap,
    register_map_for,
    settings_of,
)
from grasplink.surfaces.modbus.url import ModbusUrl, parse_modbus_url, unit_ids

logger = logging.getLogger(__name__)
# pymodbus logs what it does (a failed listen as a warning); without a handler of the
# application's, Python would print it beside our one-line error.
logging.getLogger("pymodbus").addHandler(logging.NullHandler())

START_TIMEOUT_S = 5.0
READ_HOLDING, READ_INPUTS = 3, 4
REGISTER_FUNCTIONS = frozenset({3, 4, 6, 16, 23})


@dataclass
class _Unit:
    """One gateway as one Modbus unit: what its action registers read back, and its input
    table encoded once per snapshot."""

    gateway: GatewayEdge
    last_actions: dict[str, str] = field(default_factory=dict)
    cached: tuple[Any, list[int]] | None = None  # (snapshot, its encoded table)


class ModbusServer:
    """Serve a gateway's register map over Modbus TCP or RTU; a context manager.

    `start()` returns once the server listens (or raises a BusError saying why it
    cannot: port in use, no permission, no such serial device); `stop()` closes it.
    `address` is where it listens (the port actually bound, for `tcp://...:0`).
    """

    def __init__(
        self,
        gateway: GatewayEdge | Sequence[GatewayEdge],
        url: str | ModbusUrl,
        *,
        command_timeout_s: float = COMMAND_TIMEOUT_S,
        register_map_: RegisterMap | None = None,
    ):
        gateways = [gateway] if isinstance(gateway, GatewayEdge) else list(gateway)
        self.url = parse_modbus_url(url) if isinstance(url, str) else url
        # unit id (None: every one) -> the gateway served there, in bus order
        self.units: dict[int | None, _Unit] = {
            unit: _Unit(g)
            for unit, g in zip(unit_ids(self.url, len(gateways)), gateways, strict=True)
        }
        self.gateway = gateways[0]
        # the map of the gateways' configuration (several buses: one configuration)
        self.map = register_map_ or register_map_for(gateways[0].gateway.config)
        self.command_timeout_s = command_timeout_s
        self.stats: Counter[str] = Counter()  # requests, exceptions, commands; this thread only
        self.address: ModbusUrl = self.url
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopping: asyncio.Event | None = None
        self._ready = threading.Event()
        self._stop_requested = threading.Event()  # stop() may come before the loop exists
        self._error: BaseException | None = None

    # -- control (any thread) ------------------------------------------------------------
    def start(self, timeout: float = START_TIMEOUT_S) -> ModbusServer:
        if self._thread is not None:
            raise RuntimeError("ModbusServer can only be started once")
        self._thread = threading.Thread(target=self._run, name="grasplink-modbus", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            self.stop()
            raise BusError(f"modbus: {self.url} did not start within {timeout:g} s")
        if self._error is not None:
            self._thread.join(timeout)
            raise self._error
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Close the listener and every connection (idempotent)."""
        self._stop_requested.set()
        loop, stopping = self._loop, self._stopping
        if loop is not None and stopping is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                loop.call_soon_threadsafe(stopping.set)
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout)

    def __enter__(self) -> ModbusServer:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    @property
    def native_id(self) -> int | None:
        """The server thread's OS id (per-thread CPU in benchmarks)."""
        return self._thread.native_id if self._thread is not None else None

    def describe(self) -> str:
        """One line for the CLI: where, and what the tables hold."""
        if len(self.units) > 1:
            units = "units " + ", ".join(str(u) for u in self.units) + ", a gateway each"
        elif self.address.unit is None:
            units = "every unit id"
        else:
            units = f"unit {self.address.unit}"
        devices = "".join(
            f", {r.name} at {r.address}" for r in self.map.device_registers
        )  # a configuration's device objects
        written = "".join(f", {r.name} at {r.address}" for r in self.map.device_holding)
        return (
            f"modbus {self.address} ({units}): input registers 0..{self.map.input_count - 1}"
            f"{devices}, holding registers 0..{self.map.holding_count - 1}{written} "
            "(docs/modbus.md)"
        )

    # -- the server thread ---------------------------------------------------------------
    def _run(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as exc:  # never leave start() waiting
            if self._ready.is_set():
                logger.exception("modbus: %s stopped", self.address)
            else:
                self._error = exc
        finally:
            self._ready.set()

    async def _serve(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stopping = asyncio.Event()
        server = self._make_server()
        try:
            await server.serve_forever(background=True)
        except RuntimeError:  # pymodbus logs the OSError and says only "could not listen"
            self._error = self._listen_error()
            await server.shutdown()  # type: ignore[no-untyped-call]
            return
        if isinstance(server.transport, asyncio.Server):  # TCP: the port actually bound
            host, port = server.transport.sockets[0].getsockname()[:2]
            self.address = ModbusUrl("tcp", host=host, port=port)
        self._ready.set()
        if self._stop_requested.is_set():
            self._stopping.set()
        try:
            await self._stopping.wait()
        finally:
            await server.shutdown()  # type: ignore[no-untyped-call]

    def _make_server(self) -> ModbusTcpServer | ModbusSerialServer:
        url = self.url
        devices = [
            SimDevice(
                id=unit or 0,  # 0: every unit id (TCP, one gateway)
                simdata=(
                    [SimData(0, datatype=DataType.BITS)],  # coils, discrete inputs: none,
                    [SimData(0, datatype=DataType.BITS)],  # refused (request_classes)
                    [SimData(0, count=self.map.holding_span, datatype=DataType.REGISTERS)],
                    [
                        SimData(
                            0,
                            count=self.map.input_span,
                            datatype=DataType.REGISTERS,
                            readonly=True,
                        )
                    ],
                ),
                action=self._action_of(served),
            )
            for unit, served in self.units.items()
        ]
        device = devices[0] if len(devices) == 1 else devices
        if url.scheme == "tcp":
            return ModbusTcpServer(
                device,
                address=(url.host, url.port),
                identity=_identity(),
                trace_pdu=self._trace,
                custom_pdu=request_classes(serial=False),
                ignore_missing_devices=False,  # a unit no gateway has: 0x0B
            )
        return ModbusSerialServer(
            device,
            framer=FramerType.RTU,
            port=url.device,
            baudrate=url.baud,
            parity=url.parity,
            stopbits=url.stopbits,
            bytesize=8,
            identity=_identity(),
            trace_pdu=self._trace,
            custom_pdu=request_classes(serial=True),
            ignore_missing_devices=True,  # a unit no gateway has: another device's request
        )

    def _listen_error(self) -> BusError:
        """Why listening failed, found by trying what pymodbus tried (it only logs it)."""
        url = self.url
        if url.scheme == "rtu":
            if not os.path.exists(url.device):
                return BusError(f"modbus: no serial device {url.device}")
            try:
                import serial

                serial.Serial(url.device, exclusive=True).close()
            except (OSError, ValueError) as exc:
                return BusError(f"modbus: cannot open {url.device}: {exc}")
            return BusError(f"modbus: cannot open {url.device}")
        try:
            socket.create_server((url.host, url.port)).close()
        except OSError as exc:
            hint = ""
            if exc.errno == errno.EADDRINUSE:
                hint = "; is another server running? choose another port"
            elif exc.errno == errno.EACCES and url.port < 1024:
                hint = "; ports below 1024 need privileges, use e.g. tcp://127.0.0.1:1502"
            why = os.strerror(exc.errno) if exc.errno else str(exc)
            return BusError(f"modbus: cannot listen on {url}: {why}{hint}")
        return BusError(f"modbus: cannot listen on {url}")

    def _trace(self, sending: bool, pdu: ModbusPDU) -> ModbusPDU:
        """pymodbus's `trace_pdu` hook, on each request as decoded and each answer: counts
        them, and puts in its place a request the datastore must not see. One to a unit id
        no gateway is served at becomes `_NoSuchUnit`: pymodbus then answers 0x0B over TCP
        and nothing on a serial line, where it is another device's (`ignore_missing_devices`);
        with SimDevices alone it would answer a write 0x04, failing to find the device. An
        exception-response code (81..FF) sent as a request is answered 01 (pymodbus: 04)."""
        if sending:
            if pdu.function_code & 0x80:
                self.stats["exceptions"] += 1
            return pdu
        self.stats["requests"] += 1
        if self._unit(pdu.dev_id) is None:
            self.stats["other units"] += 1
            return _NoSuchUnit(pdu)
        if isinstance(pdu, ExceptionResponse):
            return _Answer(pdu, ExcCodes.ILLEGAL_FUNCTION)
        return pdu

    def _unit(self, dev_id: int) -> _Unit | None:
        """The gateway a request's unit id addresses (None: no gateway there)."""
        return self.units.get(dev_id) or self.units.get(None)

    def _action_of(self, unit: _Unit) -> Callable[..., Any]:
        """pymodbus's per-device action for one unit's gateway."""

        async def action(*args: Any) -> ExcCodes | None:
            return await self._action(unit, *args)

        return action

    async def _action(
        self,
        unit: _Unit,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        """Called by pymodbus before each access: fill what is read, check what is written."""
        if function_code not in REGISTER_FUNCTIONS:
            return ExcCodes.ILLEGAL_FUNCTION
        offset = address - start_address
        try:
            if values is not None:
                return await self._write(unit, address, [int(v) for v in values])
            if function_code == 6:
                return None  # the echo of a single write: the registers hold what was written
            if function_code == READ_INPUTS:
                words = self.map.read_inputs(self._inputs(unit), address, count)
            else:
                settings = settings_of(unit.gateway, unit.last_actions)
                words = self.map.read_holding(
                    self.map.encode_served_holding(settings), address, count
                )
            registers[offset : offset + count] = words
        except RegisterError as exc:
            logger.debug("modbus: %s", exc)
            return ExcCodes(exc.code)
        return None

    def _inputs(self, unit: _Unit) -> list[int]:
        """A unit's encoded input table, once per snapshot (pollers faster than 20 Hz, or
        several, share one encoding)."""
        snapshot = unit.gateway.latest
        cached = unit.cached
        if cached is not None and cached[0] is snapshot:
            return cached[1]
        table = self.map.encode_served_inputs(snapshot)
        unit.cached = (snapshot, table)
        return table

    async def _write(self, unit: _Unit, address: int, words: list[int]) -> ExcCodes | None:
        command = self.map.command_for_write(address, words)  # RegisterError: nothing posted
        self.stats["commands"] += 1
        future: Future[CommandResult] = unit.gateway.post(command)
        try:
            result = await asyncio.wait_for(
                asyncio.shield(asyncio.wrap_future(future)), self.command_timeout_s
            )
        except TimeoutError:
            logger.warning(
                "modbus: %s got no result within %.1f s", command.name, self.command_timeout_s
            )
            return ExcCodes.DEVICE_FAILURE
        if result.accepted:
            if command.name in ("emg_calibrate", "restart_node"):
                unit.last_actions[command.name] = command.value
            return None
        logger.info("modbus: %s refused: %s", command.name, result.detail)
        if result.detail == MAILBOX_FULL:
            return ExcCodes.DEVICE_BUSY
        return ExcCodes.ILLEGAL_VALUE


class _Checked(ModbusPDU):
    """Put before a pymodbus request class (`request_classes`): `functions.check_request`
    judges the request's bytes before pymodbus decodes them, and a refused request is
    answered with its exception code instead of executed."""

    refusal: RegisterError | None = None

    def decode(self, data: bytes) -> None:
        self.refusal = check_request(bytes((self.function_code,)) + data)
        if self.refusal is None:
            super().decode(data)
        else:
            self.sub_function_code = -1  # no sub-function's class replaces this one

    async def datastore_update(self, context: ModbusServerContext, device_id: int) -> ModbusPDU:
        if self.refusal is not None:
            logger.debug("modbus: %s", self.refusal)
            return ExceptionResponse(self.function_code, ExcCodes(self.refusal.code))
        return await super().datastore_update(context, device_id)


#: pymodbus's request class per function code it decodes (their RTU frame sizes too)
PYMODBUS_REQUESTS: tuple[type[ModbusPDU], ...] = (
    ReadCoilsRequest,
    ReadDiscreteInputsRequest,
    ReadHoldingRegistersRequest,
    ReadInputRegistersRequest,
    WriteSingleCoilRequest,
    WriteSingleRegisterRequest,
    ReadExceptionStatusRequest,
    DiagnosticBase,
    GetCommEventCounterRequest,
    GetCommEventLogRequest,
    WriteMultipleCoilsRequest,
    WriteMultipleRegistersRequest,
    ReportDeviceIdRequest,
    ReadFileRecordRequest,
    WriteFileRecordRequest,
    MaskWriteRegisterRequest,
    ReadWriteMultipleRegistersRequest,
    ReadFifoQueueRequest,
    ReadDeviceInformationRequest,
)


def request_classes(*, serial: bool) -> list[type[ModbusPDU]]:
    """The `custom_pdu` classes: each of pymodbus's request classes behind `_Checked`, and
    over TCP a refusing class for every other function code 01..7F (their length comes
    from the MBAP header; on a serial line the frame length of a code nobody defines is
    unknown, and pymodbus skips such a frame as it always has)."""
    classes: list[type[ModbusPDU]] = [
        type(f"Checked{base.__name__}", (_Checked, base), {}) for base in PYMODBUS_REQUESTS
    ]
    if not serial:
        known = {cls.function_code for cls in PYMODBUS_REQUESTS}
        classes += [
            type(f"Function{code:02X}", (_Checked,), {"function_code": code})
            for code in range(0x01, 0x80)
            if code not in known and code not in CODES
        ]
    return classes


class _NoSuchUnit(ModbusPDU):
    """A request to a unit id no gateway is served at (put in its place by `trace_pdu`)."""

    def __init__(self, request: ModbusPDU) -> None:
        super().__init__(dev_id=request.dev_id, transaction_id=request.transaction_id)
        self.function_code = request.function_code

    async def datastore_update(self, context: ModbusServerContext, device_id: int) -> ModbusPDU:
        raise NoSuchIdException(f"no gateway at unit {device_id}")


class _Answer(ModbusPDU):
    """A request answered with an exception whatever it asked (put in its place by the
    `trace_pdu` hook): pymodbus sends what `datastore_update` returns."""

    def __init__(self, request: ModbusPDU, code: ExcCodes) -> None:
        super().__init__(dev_id=request.dev_id, transaction_id=request.transaction_id)
        self.function_code = request.function_code
        self.code = code

    async def datastore_update(self, context: ModbusServerContext, device_id: int) -> ModbusPDU:
        return ExceptionResponse(self.function_code, self.code)


def _identity() -> ModbusDeviceIdentification:
    """What Read Device Identification (2B/0E) reports (pymodbus keeps one per process)."""
    return ModbusDeviceIdentification(info=dict(IDENTIFICATION))  # type: ignore[no-untyped-call]
