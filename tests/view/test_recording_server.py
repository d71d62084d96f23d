"""`grasplink view DIR`'s HTTP over a real socket (no browser): the page told it plays a
recording, each event stream on its own clock from its query, a bad query or another
method refused, another Host not answered."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from grasplink.surfaces.view.recording import Recording, load_recording
from grasplink.surfaces.view.recording_server import RecordingView
from grasplink.surfaces.view.server import HttpAddress

WAIT_S = 60.0  # bounds for a loaded machine, never waited through when it works


@pytest.fixture(scope="module")
def recording(headline_run: Path) -> Recording:
    return load_recording(headline_run)


async def ask(port: int, head: str, *, stream: bool = False) -> bytes:
    """One request; the answer to its end, or (an event stream) up to its first frame."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(head.encode())
        await writer.drain()
        if not stream:
            return await asyncio.wait_for(reader.read(), WAIT_S)
        await asyncio.wait_for(reader.readuntil(b"data: "), WAIT_S)
        return b"data: " + await asyncio.wait_for(reader.readuntil(b"\n\n"), WAIT_S)
    finally:
        writer.close()


def get(path: str, port: int, host: str = "127.0.0.1") -> str:
    return f"GET {path} HTTP/1.1\r\nHost: {host}:{port}\r\n\r\n"


def first_frame(answer: bytes) -> dict:
    line = next(x for x in answer.split(b"\n") if x.startswith(b"data: "))
    return json.loads(line[len(b"data: ") :])  # type: ignore[no-any-return]


def test_each_stream_plays_from_its_query_and_bad_requests_are_refused(
    recording: Recording,
) -> None:
    async def main() -> None:
        stop = asyncio.Event()
        ready = asyncio.Event()
        view = RecordingView(recording, HttpAddress("127.0.0.1", 0), log=lambda _: None)
        task = asyncio.create_task(view.run(stop, lambda _: ready.set()))
        await asyncio.wait_for(ready.wait(), WAIT_S)
        port = int(view.url.rsplit(":", 1)[1].strip("/"))
        try:
            page = await ask(port, get("/", port))
            assert b"200 OK" in page and b"&quot;folder&quot;: &quot;loop-headline" in page
            paused = first_frame(await ask(port, get("/events?at=2&paused=1", port), stream=True))
            assert paused["reset"] and paused["recording"]["position_s"] == 2.0
            assert paused["recording"]["paused"] is True
            assert paused["gateways"]["loop-headline"]["newest_ts_ms"] <= 2000
            bad = await ask(port, get("/events?rate=2", port))
            assert b"400 Bad Request" in bad and b"rate: expected one of" in bad
            post = await ask(port, f"POST /events HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n")
            assert b"405" in post and b"a recording: GET only" in post
            other = await ask(port, get("/", port, "evil.example"))
            assert b"421 Misdirected Request" in other
        finally:
            stop.set()
            await asyncio.wait_for(task, WAIT_S)

    asyncio.run(main())
