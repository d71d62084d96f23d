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
- inbox full: 06 SERVER DEVICE BUSY, nothing changed, try again;
- no result in time: 04 SERVER DEVICE FAILURE; the command stays queued
  and may still be applied: read the holding registers back.

pymodbus 3.16's `SimDevice` carries the tables and calls `_action` before
every access; the action fills the registers read, or vetoes a write with an
exception code. Reads of a whole table (03, 04: what pollers send, many times a
second) are answered from the connection's data callback instead (`answer_now`):
same registers and exception codes, without a task, a loop turn and the
datastore's copy per request.

Which requests are answered at all is `functions.check_request`'s: every request PDU goes
through it before pymodbus decodes it (`_RequestDecoder`), and a function this server does
not implement, or a quantity or length the specification does not allow, is answered
with its exception code (01, 03) at once (`answer_now`), whatever pymodbus would do with it.

A process mastering several buses (`grasplink gateway --bus A --bus B`) has a gateway
per bus; one server serves them all, one unit id each (`units`): over TCP 1, 2, ...
in bus order, on a serial line the URL's unit and those after it. A request to a unit
id no gateway has is answered 0x0B GATEWAY TARGET DEVICE FAILED TO RESPOND over TCP (as
pymodbus answers it), and not at all on a serial line (another device's request).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import socket
import struct
import threading
from collections import Counter
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

from pymodbus import FramerType
from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusServerContext
from pymodbus.exceptions import ModbusIOException
from pymodbus.pdu import DecodePDU, ExceptionResponse, ModbusPDU
from pymodbus.pdu.device import ModbusDeviceIdentification
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersResponse,
    ReadInputRegistersResponse,
)
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.server.requesthandler import ServerRequestHandler
from pymodbus.simulator import DataType, SimData, SimDevice
from pymodbus.transaction import TransactionManager

from grasplink.errors import BusError
from grasplink.gateway.commands import CommandResult
from grasplink.gateway.edge import GatewayEdge
from grasplink.surfaces.modbus.functions import IDENTIFICATION, check_request
from grasplink.surfaces.modbus.registers import (
    COMMAND_TIMEOUT_S,
    RegisterError,
    RegisterMap,
    register_map,
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
        self.map = register_map_ or register_map()
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
        return (
            f"modbus {self.address} ({units}): input registers 0..{self.map.input_count - 1}, "
            f"holding registers 0..{self.map.holding_count - 1} (docs/modbus.md)"
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

    def _make_server(self) -> _TcpServer | _SerialServer:
        url = self.url
        devices = [
            SimDevice(
                id=unit or 0,  # 0: every unit id (TCP, one gateway)
                simdata=(
                    [SimData(0, datatype=DataType.BITS)],  # coils, discrete inputs: none,
                    [SimData(0, datatype=DataType.BITS)],  # refused by _Handler
                    [SimData(0, count=self.map.holding_count, datatype=DataType.REGISTERS)],
                    [
                        SimData(
                            0,
                            count=self.map.input_count,
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
        server: _TcpServer | _SerialServer
        if url.scheme == "tcp":
            # trace_pdu may return None to drop a request (pymodbus types it as returning
            # the PDU): how other units' requests stay unanswered on a shared line.
            server = _TcpServer(
                device,
                address=(url.host, url.port),
                trace_pdu=self._trace,
            )
        else:
            server = _SerialServer(
                device,
                framer=FramerType.RTU,
                port=url.device,
                baudrate=url.baud,
                parity=url.parity,
                stopbits=url.stopbits,
                bytesize=8,
                trace_pdu=self._trace,
            )
        server.answer_now = self.answer_now
        return server

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

    def _trace(self, sending: bool, pdu: ModbusPDU) -> ModbusPDU | None:
        """On a serial line, stay silent for other units' requests (and broadcasts)."""
        if sending:
            if pdu.function_code & 0x80:
                self.stats["exceptions"] += 1
            return pdu
        self.stats["requests"] += 1
        if self.url.scheme == "rtu" and pdu.dev_id not in self.units:
            self.stats["other units"] += 1
            return None  # pymodbus then neither executes nor answers it
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
                table = self._inputs(unit)
            else:
                table = self.map.encode_holding(settings_of(unit.gateway, unit.last_actions))
            registers[offset : offset + count] = self.map.read(table, address, count)
        except RegisterError as exc:
            logger.debug("modbus: %s", exc)
            return ExcCodes(exc.code)
        return None

    def answer_now(self, pdu: ModbusPDU) -> ModbusPDU | None:
        """The answer made at once, in the connection's data callback: 0x0B for a unit id no
        gateway is served at (pymodbus would answer a write 0x04, failing to find the
        device), or a register read (03, 04): the registers, or the exception `_action`
        would give (0x02 outside the table), or the exception a refused request gets
        (`functions.check_request`: 0x01, 0x03). None: pymodbus handles it."""
        unit = self._unit(pdu.dev_id)
        response: ModbusPDU
        if unit is None:
            response = ExceptionResponse(pdu.function_code, ExcCodes.GATEWAY_NO_RESPONSE)
        elif isinstance(pdu, _Refused):
            logger.debug("modbus: %s", pdu.error)
            response = pdu.response()
        elif pdu.function_code not in (READ_HOLDING, READ_INPUTS):
            return None
        else:
            response = self._read(unit, pdu)
        response.transaction_id, response.dev_id = pdu.transaction_id, pdu.dev_id
        return response

    def _read(self, unit: _Unit, pdu: ModbusPDU) -> ModbusPDU:
        try:
            response: ModbusPDU
            if pdu.function_code == READ_INPUTS:
                table = self._inputs(unit)
                response = _InputsResponse()
            else:
                table = self.map.encode_holding(settings_of(unit.gateway, unit.last_actions))
                response = _HoldingResponse()
            response.registers = self.map.read(table, pdu.address, pdu.count)
        except RegisterError as exc:
            logger.debug("modbus: %s", exc)
            response = ExceptionResponse(pdu.function_code, ExcCodes(exc.code))
        return response

    def _inputs(self, unit: _Unit) -> list[int]:
        """A unit's encoded input table, once per snapshot (pollers faster than 20 Hz, or
        several, share one encoding)."""
        snapshot = unit.gateway.latest
        cached = unit.cached
        if cached is not None and cached[0] is snapshot:
            return cached[1]
        table = self.map.encode_inputs(snapshot)
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
        if result.detail == "too many commands waiting":
            return ExcCodes.DEVICE_BUSY
        return ExcCodes.ILLEGAL_VALUE


def _pack_registers(registers: list[int]) -> bytes:
    """A read response's data (byte count, then the words) in one `struct.pack`; pymodbus
    packs and concatenates word by word."""
    return struct.pack(f">B{len(registers)}H", 2 * len(registers), *registers)


class _InputsResponse(ReadInputRegistersResponse):
    def encode(self) -> bytes:
        return _pack_registers(list(self.registers))


class _HoldingResponse(ReadHoldingRegistersResponse):
    def encode(self) -> bytes:
        return _pack_registers(list(self.registers))


class _Refused(ModbusPDU):
    """A request `functions.check_request` refuses: answered with its exception code."""

    def __init__(self, function_code: int, error: RegisterError) -> None:
        super().__init__()
        self.function_code = function_code
        self.error = error

    def response(self) -> ExceptionResponse:
        return ExceptionResponse(self.function_code, ExcCodes(self.error.code))

    async def datastore_update(self, context: ModbusServerContext, device_id: int) -> ModbusPDU:
        return self.response()  # not answered at once (a path answer_now does not take)


class _RequestDecoder(DecodePDU):
    """pymodbus's request decoder behind `functions.check_request`: a request this server
    does not answer as it is becomes a `_Refused` carrying its exception code. pymodbus
    alone would answer 07, 08, 11 (naming itself "Pymodbus"), 14, 15, 18 and others, refuse
    an exception-response code with 04, and a read of 0 or 126 registers with 80 01."""

    def decode(self, frame: bytes) -> ModbusPDU | None:
        error = check_request(frame)
        if error is not None:
            return _Refused(frame[0] if frame else 0, error)
        return super().decode(frame)


class _Handler(ServerRequestHandler):
    """pymodbus's connection handler: register reads answered in the data callback, the
    rest scheduled as a task of its own loop.

    pymodbus 3.16 schedules every request for the loop's next turn (`call_soon`), which
    hands it to the loop with `run_coroutine_threadsafe` from the loop's own thread: a
    concurrent Future, its lock and a self-pipe wake-up per request. A read needs none of
    that: `answer_now` answers it where it was decoded. Other requests (writes wait for the
    gateway) go on as a task on the same loop.
    """

    def __init__(self, *args: Any) -> None:
        super().__init__(*args)  # type: ignore[no-untyped-call]
        self._tasks: set[asyncio.Task[None]] = set()  # the loop keeps only weak references
        self._answer_now: Callable[[ModbusPDU], ModbusPDU | None] | None = getattr(
            self.server, "answer_now", None
        )

    def callback_data(self, data: bytes, addr: tuple[Any, ...] | None = None) -> int:
        """`ServerRequestHandler.callback_data` (pymodbus 3.16), reads answered at once."""
        try:
            used: int = TransactionManager.callback_data(self, data, addr)
        except ModbusIOException as exc:  # as pymodbus answers an undecodable request
            response = ExceptionResponse(
                0x00 if exc.fcode is None else exc.fcode,
                exception_code=ExcCodes.ILLEGAL_FUNCTION,
                device_id=exc.dev_id,
                transaction=exc.transaction_id,
            )
            self.server_send(response, addr)  # type: ignore[no-untyped-call]
            return len(data)
        pdu = self.last_pdu
        if pdu is None:
            return used
        broadcast = self.server.broadcast_enable and not pdu.dev_id
        answer = None if broadcast or self._answer_now is None else self._answer_now(pdu)
        if answer is not None:
            self.server_send(answer, self.last_addr)  # type: ignore[no-untyped-call]
        else:
            self.loop.call_soon(self.handle_later)
        return used

    def handle_later(self) -> None:
        task = self.loop.create_task(self.handle_request())  # type: ignore[no-untyped-call]
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)


class _TcpServer(ModbusTcpServer):
    answer_now: Callable[[ModbusPDU], ModbusPDU | None] | None = None  # ModbusServer's

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, identity=_identity(), **kwargs)
        self.decoder = _RequestDecoder(True)  # what every connection's framer decodes with

    def callback_new_connection(self) -> _Handler:
        return _Handler(self, self.trace_packet, self.trace_pdu, self.trace_connect)


class _SerialServer(ModbusSerialServer):
    answer_now: Callable[[ModbusPDU], ModbusPDU | None] | None = None  # ModbusServer's

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, identity=_identity(), **kwargs)
        self.decoder = _RequestDecoder(True)

    def callback_new_connection(self) -> _Handler:
        return _Handler(self, self.trace_packet, self.trace_pdu, self.trace_connect)


def _identity() -> ModbusDeviceIdentification:
    """What Read Device Identification (2B/0E) reports (pymodbus keeps one per process)."""
    return ModbusDeviceIdentification(info=dict(IDENTIFICATION))  # type: ignore[no-untyped-call]
