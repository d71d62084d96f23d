"""What the live view's server and a recording's have in common over asyncio: bind the
page's address, read one request per connection, stream frames to each page (Server-Sent
Events), and run until told to stop. Each server says only how it answers a request and
where its frames come from.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass

from grasplink.core.hosts import host_problem
from grasplink.errors import ConfigError
from grasplink.surfaces.view.web import (
    MAX_HEAD_BYTES,
    HostRule,
    HttpError,
    Request,
    Response,
    encode,
    encode_head,
    parse_head,
)

PUSH_S = 0.1  # a frame to each page this often: 10 updates a second
MAX_PAGES = 16  # event streams open at once; more are answered 503
HEAD_TIMEOUT_S = 10.0  # a client that sends no request head in this time is dropped
SEND_TIMEOUT_S = 5.0  # a page that takes no frame for this long is dropped
RETRY_MS = 1000  # the browser's EventSource reconnects after this long
WATCH_S = 0.2  # how often `run_until` looks at its stop condition
Log = Callable[[str], None]


@dataclass(frozen=True)
class HttpAddress:
    host: str
    port: int

    @property
    def url_host(self) -> str:
        return f"[{self.host}]" if ":" in self.host else self.host


def parse_http_address(text: str) -> HttpAddress:
    """`HOST:PORT` or `[IPv6]:PORT` (port 0: any free one); ConfigError naming it."""
    form = "expected HOST:PORT, e.g. 127.0.0.1:8642"
    if text.startswith("["):
        host, sep, port = text[1:].partition("]:")
    else:
        host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or int(port) > 65535:
        raise ConfigError(f"--http {text!r}: {form}")
    if problem := host_problem(host):
        raise ConfigError(f"--http {text!r}: {problem}")
    return HttpAddress(host, int(port))


class PageServer:
    """Binds `http` and answers each connection through `handle`; `stream` sends a page
    its frames until the server stops or the page stops taking them."""

    def __init__(self, http: HttpAddress, clock: Callable[[], float]) -> None:
        self.http = http
        self.clock = clock
        self.pages = 0
        self.url = ""
        self._hosts = HostRule(http.host, http.port)
        self._stop = asyncio.Event()

    async def handle(
        self, request: Request, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> None:
        raise NotImplementedError

    @contextlib.asynccontextmanager
    async def bound(self, stop: asyncio.Event) -> AsyncIterator[str]:
        """Listening at the page's address while inside; yields the page's URL. A bind that
        fails is a one-line error naming the address."""
        self._stop = stop
        try:
            server = await asyncio.start_server(
                self._serve, self.http.host, self.http.port, limit=MAX_HEAD_BYTES
            )
        except OSError as exc:
            raise ConfigError(f"--http {self.http.url_host}:{self.http.port}: {exc}") from None
        port = server.sockets[0].getsockname()[1]
        self._hosts = HostRule(self.http.host, port)
        self.url = f"http://{self.http.url_host}:{port}/"
        try:
            yield self.url
        finally:
            server.close()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(server.wait_closed(), 2.0)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            try:
                head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HEAD_TIMEOUT_S)
                request = parse_head(head)
            except asyncio.LimitOverrunError:
                raise HttpError(431, "request head too large") from None
            await self.handle(request, reader, writer)
        except HttpError as exc:
            writer.write(encode(Response(exc.status, f"{exc}\n".encode())))
            with contextlib.suppress(ConnectionError):
                await writer.drain()
        except (TimeoutError, asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            writer.close()
            with contextlib.suppress(ConnectionError, TimeoutError):
                await asyncio.wait_for(writer.wait_closed(), 1.0)

    async def stream(self, writer: asyncio.StreamWriter, frame: Callable[[], object]) -> None:
        """One page's event stream: `frame()` every PUSH_S; at most MAX_PAGES at once."""
        if self.pages >= MAX_PAGES:
            raise HttpError(503, f"{MAX_PAGES} pages open already")
        self.pages += 1
        try:
            writer.write(encode_head(Response(200, content_type="text/event-stream", events=True)))
            writer.write(f"retry: {RETRY_MS}\n\n".encode())
            while not self._stop.is_set():
                data = json.dumps(frame(), separators=(",", ":"), allow_nan=False)
                writer.write(f"data: {data}\n\n".encode())
                await asyncio.wait_for(writer.drain(), SEND_TIMEOUT_S)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._stop.wait(), PUSH_S)
        finally:
            self.pages -= 1


def run_until(
    run: Callable[[asyncio.Event], Awaitable[None]],
    duration_s: float | None,
    stop: Callable[[], bool],
) -> None:
    """`run(done)` in its own event loop; `done` is set once `duration_s` passed or
    `stop()` says so (looked at every WATCH_S)."""

    async def main() -> None:
        done = asyncio.Event()
        end = None if duration_s is None else time.monotonic() + duration_s

        async def watch() -> None:
            while not done.is_set():
                if stop() or (end is not None and time.monotonic() >= end):
                    done.set()
                await asyncio.sleep(WATCH_S)

        watcher = asyncio.create_task(watch())
        try:
            await run(done)
        finally:
            watcher.cancel()
            await asyncio.gather(watcher, return_exceptions=True)

    asyncio.run(main())
