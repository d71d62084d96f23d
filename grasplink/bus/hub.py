"""A loopback CAN hub: one virtual CAN bus shared by several processes.

`CanHub` wraps python-can-remote's websocket server. Each connecting client
(``remote:ws://HOST:PORT/``) gets its own python-can ``virtual`` bus on one
channel private to the hub, so every frame a client sends reaches all the
other clients (and not the sender, like a real CAN controller). The server's
bus config overrides whatever the client asks for.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import signal
import socket
import socketserver
import threading
import time
import uuid
from collections.abc import Callable
from typing import Any

from can_remote.server import RemoteServer

from grasplink.bus.url import DEFAULT_HUB_PORT
from grasplink.errors import BusError

logger = logging.getLogger(__name__)

DEFAULT_HUB_HOST = "127.0.0.1"


class _HubServer(RemoteServer):
    """RemoteServer that can be stopped: tracks and closes client connections."""

    daemon_threads = True
    block_on_close = False  # stop() joins the handler threads itself, with a timeout

    def __init__(self, host: str, port: int, **config: Any) -> None:
        self._conns: dict[threading.Thread, socket.socket] = {}
        self._conns_lock = threading.Lock()
        super().__init__(host, port, **config)

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
        logger.warning("CAN hub: connection from %s failed", client_address, exc_info=True)

    def close_clients(self, timeout: float) -> None:
        """Say goodbye to every client, then cut what is left and join the threads."""
        for protocol in list(self.clients):
            with contextlib.suppress(Exception):
                protocol._ws.close(1001, "CAN hub stopped")
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
