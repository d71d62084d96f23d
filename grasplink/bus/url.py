"""Bus URLs: one string names any CAN bus grasplink can run on.

Forms (``INTERFACE:CHANNEL[?key=value&...]``):

* ``virtual:grasplink`` - python-can's in-process bus; every handle opened on
  the same channel name in one process sees the others' frames.
* ``remote:ws://127.0.0.1:54701/`` - a client of a CAN hub (``grasplink bus
  hub``), which relays frames between processes over loopback websockets.
* ``socketcan:vcan0`` / ``socketcan:can0`` - Linux SocketCAN.
* any other python-can interface, e.g. ``pcan:PCAN_USBBUS1?bitrate=1000000``.

Query options are passed to the python-can bus as keyword arguments. Each is
checked against the options the interface accepts, and converted to the
type it takes (`grasplink.bus.options`); an unknown option or a bad value is
a `BusError` naming it and listing the accepted ones.
"""

from __future__ import annotations

import base64
import contextlib
import errno
import os
import socket
import struct
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from http.client import HTTPConnection, HTTPException, HTTPSConnection
from typing import Any
from urllib.parse import parse_qsl, urlencode, urlsplit

import can
from can.broadcastmanager import ThreadBasedCyclicSendTask
from can_remote import DEFAULT_PORT as CAN_REMOTE_DEFAULT_PORT
from can_remote.client import DEFAULT_SSL_CONTEXT, RemoteBus, RemoteClientProtocol
from can_remote.protocol import RemoteError
from can_remote.websocket import CLOSE, WebSocket, WebsocketClosed, get_accept_key

from grasplink.bus.options import convert_options, format_value
from grasplink.core.frames import Frame
from grasplink.core.hosts import host_problem
from grasplink.errors import BusError

DEFAULT_HUB_PORT = CAN_REMOTE_DEFAULT_PORT  # 54701
DEFAULT_BUS_URL = "virtual:grasplink"
URL_FORMS = (
    "expected INTERFACE:CHANNEL[?key=value&...], e.g. virtual:grasplink, "
    f"remote:ws://127.0.0.1:{DEFAULT_HUB_PORT}/, socketcan:vcan0 or "
    "pcan:PCAN_USBBUS1?bitrate=1000000"
)
HUB_CONNECT_TIMEOUT_S = 5.0


@dataclass(frozen=True)
class BusSpec:
    """A parsed bus URL: python-can interface, channel and keyword options."""

    interface: str
    channel: str
    options: dict[str, Any] = field(default_factory=dict)

    @property
    def url(self) -> str:
        """The canonical URL string (round-trips through `parse_bus_url`)."""
        text = f"{self.interface}:{self.channel}"
        if self.options:
            text += "?" + urlencode({k: format_value(v) for k, v in self.options.items()})
        return text

    def __str__(self) -> str:
        return self.url


def valid_interfaces() -> list[str]:
    """The python-can interface names a URL may start with (no udp_multicast)."""
    return sorted(set(can.interfaces.VALID_INTERFACES) - {"udp_multicast"})


def parse_bus_url(url: str) -> BusSpec:
    """Parse ``INTERFACE:CHANNEL[?key=value&...]`` into a `BusSpec`.

    Raises `BusError` naming the problem and the expected form.
    """
    if not isinstance(url, str) or not url.strip():
        raise BusError(f"empty bus URL; {URL_FORMS}")
    text = url.strip()
    interface, sep, rest = text.partition(":")
    interface = interface.strip().lower()
    if not sep or not interface:
        raise BusError(f"malformed bus URL {url!r}; {URL_FORMS}")
    if interface == "udp_multicast":
        raise BusError(
            f"bus URL {url!r}: the udp_multicast interface is not allowed - grasplink never "
            "sends CAN traffic to multicast addresses. To share a bus between processes run "
            f"`grasplink bus hub` and use remote:ws://127.0.0.1:{DEFAULT_HUB_PORT}/"
        )
    valid = valid_interfaces()
    if interface not in valid:
        raise BusError(
            f"unknown CAN interface {interface!r} in bus URL {url!r}; "
            f"valid interfaces: {', '.join(valid)}"
        )
    channel, _, query = rest.partition("?")
    channel = channel.strip()
    if not channel:
        raise BusError(f"bus URL {url!r} names no channel; {URL_FORMS}")
    pairs: list[tuple[str, str]] = []
    if query:
        try:
            pairs = parse_qsl(query, keep_blank_values=True, strict_parsing=True)
        except ValueError as exc:
            raise BusError(
                f"malformed options {query!r} in bus URL {url!r}: {exc}; "
                "expected ?key=value&key=value"
            ) from None
    options = convert_options(interface, url, pairs)
    if interface == "remote":
        channel = _normalise_hub_address(channel, url)
    return BusSpec(interface, channel, options)


def _normalise_hub_address(channel: str, url: str) -> str:
    address = channel if "://" in channel else "ws://" + channel
    try:
        parts = urlsplit(address)
        port = parts.port
    except ValueError as exc:
        raise BusError(f"bus URL {url!r}: bad hub address {channel!r} ({exc})") from None
    if parts.scheme not in ("ws", "wss"):
        raise BusError(
            f"bus URL {url!r}: a hub address starts with ws:// or wss://, not "
            f"{parts.scheme}://; e.g. remote:ws://127.0.0.1:{DEFAULT_HUB_PORT}/"
        )
    if not parts.hostname:
        raise BusError(
            f"bus URL {url!r} names no hub host; e.g. remote:ws://127.0.0.1:{DEFAULT_HUB_PORT}/"
        )
    if port == 0:
        raise BusError(f"bus URL {url!r}: hub port 0 is not a port a hub listens on")
    problem = host_problem(parts.hostname)
    if problem:
        raise BusError(f"bus URL {url!r}: bad hub host: {problem}")
    host = f"[{parts.hostname}]" if ":" in parts.hostname else parts.hostname
    port = DEFAULT_HUB_PORT if port is None else port
    return f"{parts.scheme}://{host}:{port}{parts.path or '/'}"


def socketcan_available() -> bool:
    """True when this kernel can open a raw CAN socket (AF_CAN)."""
    family = getattr(socket, "AF_CAN", None)
    if family is None:
        return False
    try:
        sock = socket.socket(family, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError:
        return False
    sock.close()
    return True


def open_bus(url: str, *, receive_own_messages: bool = False) -> can.BusABC:
    """Open the python-can bus a URL names (see the module docstring).

    Own frames are echoed back if either ``receive_own_messages`` or the URL
    option of that name asks for it. The caller owns the bus and must call
    ``shutdown()``. Every failure is a `BusError` naming the URL.
    """
    spec = parse_bus_url(url)
    kwargs = dict(spec.options)
    kwargs["receive_own_messages"] = bool(
        receive_own_messages or kwargs.get("receive_own_messages", False)
    )
    if spec.interface == "remote":
        return _open_hub_client(spec, kwargs)
    if spec.interface == "socketcan" and not socketcan_available():
        raise BusError(_no_socketcan_message(spec))
    try:
        return can.Bus(interface=spec.interface, channel=spec.channel, ignore_config=True, **kwargs)
    except Exception as exc:
        raise BusError(_open_failure_message(spec, exc)) from exc


def _no_socketcan_message(spec: BusSpec) -> str:
    return (
        f"cannot open {spec.url}: SocketCAN is not available on this kernel (no AF_CAN "
        "support). Use virtual:grasplink to run every node in one process, or start a hub "
        f"with `grasplink bus hub` and use remote:ws://127.0.0.1:{DEFAULT_HUB_PORT}/ to "
        "connect several processes (see docs/buses.md)"
    )


def _errno_of(exc: BaseException) -> int | None:
    seen: BaseException | None = exc
    while seen is not None:
        code = getattr(seen, "errno", None) or getattr(seen, "error_code", None)
        if isinstance(code, int):
            return code
        seen = seen.__cause__ or seen.__context__
    return None


def _open_failure_message(spec: BusSpec, exc: Exception) -> str:
    detail = str(exc) or type(exc).__name__
    code = _errno_of(exc)
    if spec.interface == "socketcan":
        if code == errno.EAFNOSUPPORT:
            return _no_socketcan_message(spec)
        if code == errno.ENODEV:
            if spec.channel.startswith("vcan"):
                how = (
                    f"create it with: sudo modprobe vcan; sudo ip link add dev {spec.channel} "
                    f"type vcan; sudo ip link set up {spec.channel}"
                )
            else:
                how = "check the adapter is plugged in and `ip link show` lists it"
            return f"cannot open {spec.url}: no CAN network interface {spec.channel!r}; {how}"
        if code == errno.ENETDOWN:
            return (
                f"cannot open {spec.url}: {spec.channel} is down; bring it up with: "
                f"sudo ip link set up {spec.channel}"
            )
    return f"cannot open CAN bus {spec.url}: {detail}"


class _HubWebSocket(WebSocket):
    """can_remote's client websocket, with a timeout on connect and handshake.

    `secure` says whether the socket is TLS: python-can-remote keeps that in a private
    flag its own `connect` sets, so `close` here does what its close does for TLS.
    """

    secure = False
    closed: bool  # WebSocket's (set in its __init__)

    def __init__(self, url: str, protocols: list[str], *, ssl_context: Any, timeout: float):
        self._connect_timeout = timeout
        super().__init__(url, protocols, ssl_context=ssl_context)

    def connect(self, protocols, headers=None, ssl_context=None):
        # WebSocket.connect as in python-can-remote 0.3.0, plus the timeout.
        o = urlsplit(self.url)
        if o.scheme == "wss":
            conn: HTTPConnection = HTTPSConnection(
                o.netloc, context=ssl_context, timeout=self._connect_timeout
            )
            self.secure = True
        else:
            conn = HTTPConnection(o.netloc, timeout=self._connect_timeout)
        try:
            conn.connect()
        except OSError as exc:
            raise _HubUnreachable(exc) from exc
        try:
            key = base64.b64encode(os.urandom(16)).decode()
            headers = dict(headers or {})
            headers["User-Agent"] = f"python-can/{can.__version__} (grasplink)"
            headers["Upgrade"] = "WebSocket"
            headers["Connection"] = "Upgrade"
            headers["Sec-WebSocket-Key"] = key
            headers["Sec-WebSocket-Version"] = "13"
            if protocols:
                headers["Sec-WebSocket-Protocol"] = ",".join(protocols)
            conn.request("GET", o.path or "/", headers=headers)
            res = conn.getresponse()
            if res.status != 101 or (res.getheader("Upgrade") or "").lower() != "websocket":
                raise _NotAHub(f"HTTP {res.status} {res.reason} instead of a websocket upgrade")
            if res.getheader("Sec-WebSocket-Accept") != get_accept_key(key):
                raise _NotAHub("bad Sec-WebSocket-Accept")
            self.protocol = res.getheader("Sec-WebSocket-Protocol")
            if protocols and self.protocol not in protocols:
                raise _NotAHub(f"unsupported websocket protocol {self.protocol!r}")
        except BaseException:
            conn.close()
            raise
        self.socket = conn.sock
        self.socket.settimeout(None)  # can_remote waits with select() from here on

    def close(self, status: int | None = None, reason: str = "") -> None:
        if not self.secure:
            super().close(status, reason)  # the close frame, then a half-close
            return
        # TLS has no half-close: the close frame alone, as python-can-remote 0.3.0 does for it
        if not self.closed:
            payload = struct.pack(">H", status) + reason.encode() if status else b""
            try:
                self.send_frame(CLOSE, payload)
            finally:
                self.closed = True


class _NotAHub(Exception):
    pass


class _HubUnreachable(Exception):
    def __init__(self, cause: OSError):
        super().__init__(cause.strerror or str(cause))
        self.refused = isinstance(cause, ConnectionRefusedError)
        self.unresolved = isinstance(cause, socket.gaierror)


class BusDisconnected(can.CanOperationError):
    """The bus handle is gone for good (e.g. its hub connection closed): only reopening helps."""


class HubClientBus(RemoteBus):
    """A client of a CAN hub (python-can-remote's `RemoteBus`, made robust).

    Connecting times out instead of hanging. python-can-remote 0.3.0 reports
    a hub that went away as a leaked ``WebsocketClosed`` (1006 when the socket
    just closed, the hub's code when it said goodbye), then ``ValueError`` or
    ``OSError`` from the dead socket; here ``recv``/``send`` raise
    `BusDisconnected` instead, and ``shutdown`` finishes in bounded time (the
    stock one can spin or raise when the connection is already gone). The
    handle never recovers: reconnecting means opening a new one.
    """

    _shut_down = True  # until built: nothing to shut down

    def __init__(
        self,
        channel: str,
        ssl_context: Any = None,
        *,
        connect_timeout: float = HUB_CONNECT_TIMEOUT_S,
        **config: Any,
    ) -> None:
        # RemoteBus.__init__ (python-can-remote 0.3.0) with a bounded connect.
        url = channel if "://" in channel else "ws://" + channel
        websocket = _HubWebSocket(
            url,
            ["can.binary+json.v1", "can.json.v1"],
            ssl_context=DEFAULT_SSL_CONTEXT if ssl_context is None else ssl_context,
            timeout=connect_timeout,
        )
        try:
            self.remote_protocol = RemoteClientProtocol(config, websocket)
        except BaseException:
            with contextlib.suppress(OSError):
                websocket.socket.close()
            raise
        self.socket = websocket.socket
        self.websocket = websocket  # ours: built here, so no need to reach into the protocol
        self.channel_info = self.remote_protocol.channel_info
        self.channel = channel
        self._periodic_lock = threading.Lock()
        can.BusABC.__init__(self, channel)
        self._shut_down = False

    def _send_periodic_internal(
        self,
        msgs: Sequence[can.Message] | can.Message,
        period: float,
        duration: float | None = None,
        autostart: bool = True,
        modifier_callback: Callable[[can.Message], None] | None = None,
    ) -> can.broadcastmanager.CyclicSendTaskABC:
        """Periodic frames sent from this process by python-can's own thread task.

        python-can-remote 0.3.0 asks the hub to send them instead, and its task's
        modify_data raises TypeError (``super(self)``): python-canopen calls it on every
        change of a heartbeat's state byte, so a canopen LocalNode's heartbeat producer
        (or ``network.send_periodic``) could not run on a hub. Sent from here, a heartbeat
        also stops when this process hangs or dies, which is what it vouches for; the hub
        sending it would keep a hung node looking alive. This is BusABC's own
        implementation (the hook python-can documents for backends to override).
        """
        return ThreadBasedCyclicSendTask(
            bus=self,
            lock=self._periodic_lock,
            messages=msgs,
            period=period,
            duration=duration,
            autostart=autostart,
            modifier_callback=modifier_callback,
        )

    def recv(self, timeout: float | None = None) -> can.Message | None:
        try:
            return super().recv(timeout)
        except (WebsocketClosed, OSError, ValueError) as exc:
            raise BusDisconnected(f"connection to CAN hub {self.channel} closed ({exc})") from exc

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.websocket.closed:
            raise BusDisconnected(f"connection to CAN hub {self.channel} is closed")
        try:
            super().send(msg, timeout)
        except (OSError, ValueError) as exc:
            raise BusDisconnected(f"connection to CAN hub {self.channel} closed ({exc})") from exc

    def shutdown(self) -> None:
        if self._shut_down:
            return
        self._shut_down = True
        self.stop_all_periodic_tasks()  # before the socket closes under their threads
        ws = self.websocket
        try:
            if not ws.closed:
                ws.close()
            deadline = time.monotonic() + 2.0
            while time.monotonic() < deadline:  # let the hub answer our close frame
                self.remote_protocol.recv(0.1)
        except (WebsocketClosed, OSError, ValueError, can.CanError):
            pass
        finally:
            with contextlib.suppress(OSError):
                ws.socket.close()
            can.BusABC.shutdown(self)


def _open_hub_client(spec: BusSpec, kwargs: dict[str, Any]) -> HubClientBus:
    port = urlsplit(spec.channel).port or DEFAULT_HUB_PORT
    start_hint = f"start one with `grasplink bus hub --port {port}`"
    try:
        return HubClientBus(spec.channel, **kwargs)
    except _HubUnreachable as exc:
        if exc.unresolved:  # no hub to start there: the name is wrong or DNS is down
            host = urlsplit(spec.channel).hostname
            raise BusError(f"cannot resolve hub host {host!r} in {spec.url} ({exc})") from None
        why = "" if exc.refused else f" ({exc})"
        raise BusError(f"no CAN hub at {spec.channel}{why} — {start_hint}") from None
    except (TimeoutError, _NotAHub, HTTPException, WebsocketClosed, RemoteError) as exc:
        raise BusError(
            f"{spec.channel} did not answer as a CAN hub ({str(exc) or type(exc).__name__}) — "
            f"is it a `grasplink bus hub`? Otherwise {start_hint}"
        ) from None
    except Exception as exc:
        raise BusError(f"cannot connect to CAN hub {spec.channel}: {exc}") from exc


def frame_to_message(frame: Frame, timestamp: float | None = None) -> can.Message:
    """The python-can message for a grasplink `Frame` (11-bit, classic CAN)."""
    return can.Message(
        arbitration_id=frame.can_id,
        is_extended_id=False,
        is_remote_frame=frame.rtr,
        dlc=frame.length,
        data=None if frame.rtr else frame.data,
        timestamp=0.0 if timestamp is None else timestamp,
    )


def message_to_frame(msg: can.Message) -> Frame | None:
    """The `Frame` for a python-can message, or None if CANopen cannot carry it.

    Error frames, 29-bit identifiers and CAN FD frames give None; callers
    count them rather than fail.
    """
    if msg.is_error_frame or msg.is_extended_id or msg.is_fd:
        return None
    if not 0 <= msg.arbitration_id <= 0x7FF:
        return None
    if msg.is_remote_frame:
        return Frame(msg.arbitration_id, b"", rtr=True, dlc=min(msg.dlc, 8))
    data = bytes(msg.data)
    if len(data) > 8:
        return None
    return Frame(msg.arbitration_id, data)
