"""`grasplink view DIR`'s edge: the live page's HTTP server, playing a recording instead of
following a broker (docs/view.md, Recordings).

Each page's event stream carries its own playback (`playback.PagePlayback`): where to
start, the speed and whether paused come in the stream's query (`/events?at=12.5&rate=1
&paused=0`), and the page opens a new stream to pause, play, seek or change speed, so
the clock is the server's, one per page, and nothing but GET is answered.
"""

from __future__ import annotations

import asyncio
import html
import json
import math
import time
from collections.abc import Callable
from urllib.parse import parse_qs

from grasplink.surfaces.view.pages import HttpAddress, Log, PageServer, run_until
from grasplink.surfaces.view.playback import RATES, PagePlayback, PlaybackClock
from grasplink.surfaces.view.recording import Recording
from grasplink.surfaces.view.web import HttpError, Request, Response, encode, load_files, respond

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


class RecordingView(PageServer):
    """Serves the page over `recording`; `run` until `stop` is set."""

    def __init__(
        self,
        recording: Recording,
        http: HttpAddress,
        *,
        log: Log = print,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        super().__init__(http, clock)
        self.recording = recording
        self.log = log
        files = load_files()
        self._files = {**files, "/": page_for(files["/"], recording)}

    async def run(self, stop: asyncio.Event, on_ready: Callable[[str], None]) -> None:
        async with self.bound(stop) as url:
            on_ready(url)
            await stop.wait()

    async def handle(
        self, request: Request, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> None:
        response = respond(request, self._hosts, self._files)
        if response.status == 405:
            response = Response(405, b"a recording: GET only\n")
        if response.events and request.method == "GET":
            clock = playback_from(request.query, self.recording.duration_s, self.clock())
            page = PagePlayback(self.recording, clock)
            await self.stream(writer, lambda: page.frame(self.clock()))
        else:
            writer.write(encode(response, head_only=request.method == "HEAD"))
            await writer.drain()


def serve_recording(
    recording: Recording,
    http: HttpAddress,
    *,
    duration_s: float | None = None,
    log: Log = print,
    stop: Callable[[], bool] = lambda: False,
) -> None:
    """Serve the page over `recording` until `duration_s` passed or `stop()` says so."""

    view = RecordingView(recording, http, log=log)
    about = f"{recording.folder}, {recording.duration_s:g} s; {recording.settings}"

    async def run(done: asyncio.Event) -> None:
        await view.run(done, lambda url: log(f"view: {url} (recording {about})"))

    run_until(run, duration_s, stop)
