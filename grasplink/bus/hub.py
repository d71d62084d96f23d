"""A loopback CAN hub: one virtual CAN bus shared by several processes.

`CanHub` wraps python-can-remote's websocket server. Each connecting client
(``remote:ws://HOST:PORT/``) gets its own python-can ``virtual`` bus on one
channel private to the hub, so every frame a client sends reaches all the
other clients (and not the sender, like a real CAN controller). The server's
bus config overrides whatever the client asks for.

A client that drops (killed, unplugged, reset) is normal for a hub: it logs one
line naming the client and why, and serves the others on. python-can-remote
0.3.0 let the dropped socket's errors escape both of a session's threads (two
tracebacks a client); `_HubSession` and `_HubRequestHandler` serve a session
the same way, ending it quietly instead.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import signal
import socket
import socketserver
import sys
import threading
import time
import uuid
from collections.abc import Callable
from typing import Any

import can
from can_remote.protocol import RemoteError
from can_remote.server import (
    ClientRequestHandler,
    RemoteServer,
    RemoteServerError,
    RemoteServerProtocol,
)
from can_remote.websocket import WebSocket, WebsocketClosed, get_accept_key

from grasplink.bus.url import DEFAULT_HUB_PORT
from grasplink.errors import BusError

logger = logging.getLogger(__name__)

DEFAULT_HUB_HOST = "127.0.0.1"


# What a client that went away looks like from its socket (reset, broken pipe, closed fd).
_GONE = (OSError, ValueError, WebsocketClosed, RemoteError)
# Close codes of a client that said goodbye (normal closure, going away).
_GOODBYE = (1000, 1001)


def _address(client_address: Any) -> str:
    """HOST:PORT of a client (its socket's peer address)."""
    host, port = tuple(client_address)[:2]
    return f"[{host}]:{port}" if ":" in str(host) else f"{host}:{port}"


def _why(exc: BaseException) -> str:
    """A client's departure in a few words."""
    if isinstance(exc, WebsocketClosed):
        if exc.code == 1006:  # python-can-remote's code for a socket that just closed
            return "connection closed without a goodbye"
        return f"closed with code {exc.code}{': ' + exc.reason if exc.reason else ''}"
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror.lower()
    return str(exc) or type(exc).__name__


class _HubSession(RemoteServerProtocol):
    """One client's session: RemoteServerProtocol's loops, ending quietly when the client goes.

    The receiving loop (the handler's thread) and the sending loop (a thread of
    its own) do what python-can-remote 0.3.0's do, on our own thread and table of
    periodic tasks, except that a dead socket in either ends the session for both,
    and its reason is kept for one log line.
    """

    def __init__(self, config: dict[str, Any], websocket: WebSocket, address: str) -> None:
        self.websocket = websocket
        self.address = address
        self.ended: BaseException | None = None  # why the session ended (first seen)
        super().__init__(config, websocket)
        # our own sending thread and periodic tasks (the base's are private to it: unused)
        self._sender = threading.Thread(target=self._bus_to_client, daemon=True)
        self._periodic: dict[int, Any] = {}  # CAN-ID -> the bus's (modifiable) periodic task

    def run(self) -> None:
        self._sender.start()
        try:
            self._client_to_bus()
        except _GONE as exc:
            self._end(exc)
        finally:
            self._end(None)
            if self._sender.is_alive():
                self._sender.join(3)

    def _end(self, why: BaseException | None) -> None:
        """Stop both loops; the first reason given is the one logged."""
        if why is not None and self.ended is None:
            self.ended = why
        self.running = False
        with contextlib.suppress(OSError):  # wakes the receiving loop out of its select()
            self.websocket.socket.shutdown(socket.SHUT_RDWR)

    def _bus_to_client(self) -> None:
        try:
            while self.running:
                msg = self.bus.recv(0.5)
                if msg is not None:
                    self.send_msg(msg)
        except _GONE as exc:
            self._end(exc)
        finally:
            self.bus.shutdown()

    def _client_to_bus(self) -> None:
        while self.running:
            event = self.recv()
            if event is None:
                continue
            if isinstance(event, can.Message):
                self.bus.send(event)
            elif event["type"] == "periodic_start":
                msg = can.Message(**event["payload"]["msg"])
                task = self._periodic.get(msg.arbitration_id)
                if task is not None:
                    task.modify_data(msg)
                else:
                    self._periodic[msg.arbitration_id] = self.bus.send_periodic(
                        msg, event["payload"]["period"], event["payload"].get("duration")
                    )
            elif event["type"] == "periodic_stop":
                stopped = self._periodic.pop(event["payload"], None)
                if stopped is not None:
                    stopped.stop()


class _HubRequestHandler(ClientRequestHandler):
    """python-can-remote's handler with `_HubSession`: one line when a client goes."""

    def start_websocket(self) -> None:
        # ClientRequestHandler.start_websocket as in python-can-remote 0.3.0, with our session.
        self.send_response(101)
        self.send_header("Upgrade", "WebSocket")
        self.send_header("Connection", "Upgrade")
        self.send_header("Sec-WebSocket-Accept", get_accept_key(self.headers["Sec-WebSocket-Key"]))
        offered = [p.strip() for p in self.headers.get("Sec-WebSocket-Protocol", "").split(",")]
        protocol = "can.binary+json.v1" if "can.binary+json.v1" in offered else "can.json.v1"
        self.send_header("Sec-WebSocket-Protocol", protocol)
        self.end_headers()
        address = _address(self.client_address)
        server = self.server
        assert isinstance(server, _HubServer)
        try:
            session = _HubSession(
                server.config, WebSocket(None, protocol, sock=self.request), address
            )
        except _GONE as exc:
            logger.warning("CAN hub: client %s left before joining (%s)", address, _why(exc))
            return
        except RemoteServerError as exc:  # spoke websocket, but not python-can-remote
            logger.warning("CAN hub: refused client %s (%s)", address, exc)
            return
        logger.info("CAN hub: client %s joined", address)
        server.clients.append(session)
        try:
            session.run()
        finally:
            server.clients.remove(session)
        why = session.ended
        if why is None or (isinstance(why, WebsocketClosed) and why.code in _GOODBYE):
            logger.info("CAN hub: client %s left", address)
        else:
            logger.warning("CAN hub: client %s dropped (%s)", address, _why(why))


class _HubServer(RemoteServer):
    """RemoteServer that can be stopped: tracks and closes client connections."""

    daemon_threads = True
    block_on_close = False  # stop() joins the handler threads itself, with a timeout

    def __init__(self, host: str, port: int, **config: Any) -> None:
        self._conns: dict[threading.Thread, socket.socket] = {}
        self._conns_lock = threading.Lock()
        super().__init__(host, port, **config)
        self.RequestHandlerClass = _HubRequestHandler  # socketserver's documented attribute

    def server_bind(self) -> None:
        # HTTPServer.server_bind resolves the host's FQDN, which can stall
        # without DNS; the name is never used here.
        socketserver.TCPServer.server_bind(self)
        host, port = self.server_address[:2]
        self.server_name, self.server_port = str(host), int(port)

    def process_request(self, request: Any, client_address: Any) -> None:
        thread = threading.Thread(
            target=self._serve_client,
            args=(request, client_address),
            name=f"grasplink-hub-client-{client_address[1]}",
            daemon=True,
        )
        with self._conns_lock:
            self._conns[thread] = request
        thread.start()

    def _serve_client(self, request: Any, client_address: Any) -> None:
        try:
            self.process_request_thread(request, client_address)
        finally:
            with self._conns_lock:
                self._conns.pop(threading.current_thread(), None)

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A connection that failed outside a session: one line if the client went away,
        a traceback only for what would be a bug."""
        exc = sys.exc_info()[1]
        address = _address(client_address)
        if isinstance(exc, _GONE):
            logger.warning("CAN hub: connection from %s dropped (%s)", address, _why(exc))
        else:
            logger.warning("CAN hub: connection from %s failed", address, exc_info=True)

    def close_clients(self, timeout: float) -> None:
        """Say goodbye to every client, then cut what is left and join the threads."""
        for session in list(self.clients):
            with contextlib.suppress(Exception):
                session.websocket.close(1001, "CAN hub stopped")
        deadline = time.monotonic() + timeout
        self._join_handlers(time.monotonic() + min(0.5, timeout / 2))
        with self._conns_lock:
            leftovers = list(self._conns.values())
        for sock in leftovers:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
        self._join_handlers(deadline)

    def _join_handlers(self, deadline: float) -> None:
        with self._conns_lock:
            threads = list(self._conns)
        for thread in threads:
            thread.join(max(0.0, deadline - time.monotonic()))

    @property
    def handler_count(self) -> int:
        with self._conns_lock:
            return len(self._conns)


class CanHub:
    """A CAN hub serving ``remote:`` clients on HOST:PORT (port 0: ephemeral).

    Binds 127.0.0.1 by default. Use as a context manager or call `start()` /
    `stop()`; `url` is the bus URL clients pass to ``--bus``.
    """

    def __init__(
        self,
        host: str = DEFAULT_HUB_HOST,
        port: int = DEFAULT_HUB_PORT,
        *,
        channel: str | None = None,
    ) -> None:
        if not 0 <= port <= 65535:
            raise BusError(f"hub port {port} is outside 0..65535")
        self.host = host
        self._requested_port = port
        self._bound_port: int | None = None
        self.channel = channel or f"grasplink-hub-{uuid.uuid4().hex[:12]}"
        self._server: _HubServer | None = None
        self._thread: threading.Thread | None = None

    @property
    def port(self) -> int:
        """The bound port (the ephemeral one when started with port 0)."""
        return self._requested_port if self._bound_port is None else self._bound_port

    @property
    def url(self) -> str:
        """The bus URL a client on this machine uses to join the hub."""
        host = "127.0.0.1" if self.host in ("", "0.0.0.0") else self.host
        if ":" in host:
            host = f"[{host}]"
        return f"remote:ws://{host}:{self.port}/"

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def client_count(self) -> int:
        """Clients currently connected."""
        return len(self._server.clients) if self._server else 0

    def start(self) -> CanHub:
        if self._server is not None:
            raise RuntimeError("CanHub already started")
        try:
            server = _HubServer(
                self.host,
                self._requested_port,
                interface="virtual",
                channel=self.channel,
                ignore_config=True,
            )
        except OSError as exc:
            hint = ""
            if exc.errno == errno.EADDRINUSE:
                hint = " — is a hub already running there? Pick another --port"
            raise BusError(
                f"cannot start a CAN hub on {self.host}:{self._requested_port}: "
                f"{exc.strerror or exc}{hint}"
            ) from None
        self._server = server
        self._bound_port = server.server_port
        self._thread = threading.Thread(
            target=server.serve_forever,
            kwargs={"poll_interval": 0.1},
            name=f"grasplink-hub-{server.server_port}",
            daemon=True,
        )
        self._thread.start()
        logger.info("CAN hub listening on %s (virtual channel %s)", self.url, self.channel)
        return self

    def stop(self, timeout: float = 3.0) -> None:
        """Stop serving, disconnect every client and close the socket."""
        server, thread = self._server, self._thread
        if server is None or thread is None:
            return
        if thread.is_alive():
            server.shutdown()
        thread.join(timeout)
        server.close_clients(timeout)
        server.server_close()
        if server.handler_count:
            logger.warning("CAN hub: %d client thread(s) did not stop", server.handler_count)
        self._server = None
        self._thread = None
        logger.info("CAN hub on port %d stopped", server.server_port)

    def __enter__(self) -> CanHub:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()


def run_hub(
    host: str = DEFAULT_HUB_HOST,
    port: int = DEFAULT_HUB_PORT,
    *,
    out: Callable[[str], None] | None = None,
) -> None:
    """Serve a hub until SIGINT/SIGTERM (``grasplink bus hub``).

    Prints the URL clients should use; raises `BusError` if it cannot bind.
    """
    say = out or (lambda line: print(line, flush=True))
    stop = threading.Event()
    previous: dict[signal.Signals, Any] = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda _signum, _frame: stop.set())
    hub = CanHub(host, port)
    try:
        hub.start()
        say(f"CAN hub listening on {host}:{hub.port}")
        say(f"connect nodes with: --bus {hub.url}")
        while not stop.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        hub.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    say("CAN hub stopped")
