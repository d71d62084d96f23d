"""`grasplink view DIR`'s edge: the live page's HTTP server, playing a recording instead of
following a broker (docs/view.md, Recordings).

Each page's event stream carries its own playback (`playback.PagePlayback`): where to
start, the speed and whether paused come in the stream's query (`/events?at=12.5&rate=1
&paused=0`), and the page opens a new stream to pause, play, seek or change speed, so
the clock is the server's, one per page, and nothing but GET is answered.
"""

from __future__ import annotations

import asyncio
import contextlib
import html
import json
import math
import time
from collections.abc import Callable
from urllib.parse import parse_qs

from grasplink.errors import ConfigError
from grasplink.surfaces.view.playback import RATES, PagePlayback, PlaybackClock
from grasplink.surfaces.view.recording import Recording
from grasplink.surfaces.view.server import (
    HEAD_TIMEOUT_S,
    MAX_PAGES,
    PUSH_S,
    RETRY_MS,
    SEND_TIMEOUT_S,
    HttpAddress,
    Log,
)
from grasplink.surfaces.view.web import (
    MAX_HEAD_BYTES,
    HostRule,
    HttpError,
    Response,
    encode,
    encode_head,
    load_files,
    parse_head,
    respond,
)

#: where the page learns it shows a recording: filled in with what it is
RECORDING_META = b'<meta name="grasplink-recording" content="">'


def page_for(page: bytes, recording: Recording) -> bytes:
    """The page, told it plays `recording` (its folder, length, rates, settings)."""
    about = {
        "folder": recording.folder.name,
        "duration_s": recording.duration_s,
        "rates": list(RATES),
        "settings": recording.settings,
    }
    meta = f'<meta name="grasplink-recording" content="{html.escape(json.dumps(about))}">'
    return page.replace(RECORDING_META, meta.encode(), 1)


def playback_from(query: str, duration_s: float, wall_s: float) -> PlaybackClock:
    """A page's clock from its stream's query: `at` (s in the run), `rate`, `paused` (0/1)."""
    fields = parse_qs(query, keep_blank_values=True)

    def one(name: str, default: str) -> str:
        values = fields.get(name, [default])
        if len(values) != 1:
            raise HttpError(400, f"{name}: given {len(values)} times")
        return values[0]

    try:
        at, rate = float(one("at", "0")), float(one("rate", "1"))
    except ValueError:
        raise HttpError(400, "at and rate: expected numbers") from None
    if not math.isfinite(at) or at < 0:
        raise HttpError(400, f"at: expected seconds >= 0 in the run, got {one('at', '0')}")
    if rate not in RATES:
        raise HttpError(400, f"rate: expected one of {', '.join(map(str, RATES))}")
    paused = one("paused", "0")
    if paused not in ("0", "1"):
        raise HttpError(400, "paused: expected 0 or 1")
    return PlaybackClock(duration_s, at, wall_s, rate, paused == "1")


class RecordingView:
    """Serves the page over `recording`; `run` until `stop` is set."""

    def __init__(
        self,
        recording: Recording,
        http: HttpAddress,
        *,
        log: Log = print,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.recording = recording
        self.http = http
        self.log = log
        self.clock = clock
        self.pages = 0
        self.url = ""
        files = load_files()
        self._files = {**files, "/": page_for(files["/"], recording)}
        self._hosts = HostRule(http.host, http.port)
        self._stop = asyncio.Event()

    async def run(self, stop: asyncio.Event, on_ready: Callable[[str], None]) -> None:
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
        on_ready(self.url)
        try:
            await stop.wait()
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
            response = respond(request, self._hosts, self._files)
            if response.status == 405:
                response = Response(405, b"a recording: GET only\n")
            if response.events and request.method == "GET":
                clock = playback_from(request.query, self.recording.duration_s, self.clock())
                await self._stream(writer, PagePlayback(self.recording, clock))
            else:
                writer.write(encode(response, head_only=request.method == "HEAD"))
                await writer.drain()
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

    async def _stream(self, writer: asyncio.StreamWriter, page: PagePlayback) -> None:
        """One page's event stream: a frame every PUSH_S of its own playback."""
        if self.pages >= MAX_PAGES:
            raise HttpError(503, f"{MAX_PAGES} pages open already")
        self.pages += 1
        try:
            writer.write(encode_head(Response(200, content_type="text/event-stream", events=True)))
            writer.write(f"retry: {RETRY_MS}\n\n".encode())
            while not self._stop.is_set():
                data = json.dumps(page.frame(self.clock()), separators=(",", ":"), allow_nan=False)
                writer.write(f"data: {data}\n\n".encode())
                await asyncio.wait_for(writer.drain(), SEND_TIMEOUT_S)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._stop.wait(), PUSH_S)
        finally:
            self.pages -= 1


def serve_recording(
    recording: Recording,
    http: HttpAddress,
    *,
    duration_s: float | None = None,
    log: Log = print,
    stop: Callable[[], bool] = lambda: False,
) -> None:
    """Serve the page over `recording` until `duration_s` passed or `stop()` says so."""

    async def main() -> None:
        done = asyncio.Event()
        view = RecordingView(recording, http, log=log)
        end = None if duration_s is None else time.monotonic() + duration_s

        async def watch() -> None:
            while not done.is_set():
                if stop() or (end is not None and time.monotonic() >= end):
                    done.set()
                await asyncio.sleep(0.2)

        watcher = asyncio.create_task(watch())
        try:
            about = f"{recording.folder}, {recording.duration_s:g} s; {recording.settings}"
            await view.run(done, lambda url: log(f"view: {url} (recording {about})"))
        finally:
            watcher.cancel()
            await asyncio.gather(watcher, return_exceptions=True)

    asyncio.run(main())
