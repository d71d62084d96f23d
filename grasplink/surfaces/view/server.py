"""The live view's edge: one asyncio loop holding the MQTT subscription (aiomqtt, public
API only) and a small HTTP server streaming frames to each page (Server-Sent Events).

Everything the page shows is `state.ViewState`'s; this module only moves bytes and
reads the clock. Read-only unless commands are allowed: then it publishes the commands
`commands.prepare` passed, and nothing else, and hands the page the gateway's reply.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import random
import ssl
import time
from collections.abc import Callable
from dataclasses import dataclass

import aiomqtt

from grasplink.core.hosts import host_problem
from grasplink.errors import BrokerError, ConfigError
from grasplink.surfaces.telemetry.url import BrokerUrl
from grasplink.surfaces.view.commands import (
    REPLY_TIMEOUT_S,
    CommandRefused,
    Reply,
    Tokens,
    prepare,
    read_reply,
)
from grasplink.surfaces.view.state import ROOT, ViewState
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

PUSH_S = 0.1  # a frame to each page this often: 10 updates a second
MAX_PAGES = 16  # event streams open at once; more are answered 503
HEAD_TIMEOUT_S = 10.0  # a client that sends no request head in this time is dropped
SEND_TIMEOUT_S = 5.0  # a page that takes no frame for this long is dropped
CONNECT_TIMEOUT_S = 5.0
BACKOFF_MIN_S, BACKOFF_MAX_S = 0.5, 5.0  # short: the page shows the broker back soon
RETRY_MS = 1000  # the browser's EventSource reconnects after this long
MAX_PENDING = 16  # commands waiting for their reply at once; more are answered 503
MQTT_LOGGER = logging.getLogger("grasplink.view.mqtt")
MQTT_LOGGER.addHandler(logging.NullHandler())
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


class LiveView:
    """Subscribes to the JSON tree, serves the page; `run` until `stop` is set."""

    def __init__(
        self,
        broker: BrokerUrl,
        http: HttpAddress,
        *,
        gateway_id: str | None = None,
        tls: ssl.SSLContext | None = None,
        allow_commands: bool = False,
        log: Log = print,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.broker = broker
        self.http = http
        self.tls = tls
        self.log = log
        self.clock = clock
        self.state = ViewState(gateway_id)
        self.topic = f"{ROOT}/{gateway_id or '+'}/#"
        self.pages = 0
        self.url = ""
        self._files = load_files()
        self._hosts = HostRule(http.host, http.port)
        self._stop = asyncio.Event()
        self.tokens = Tokens() if allow_commands else None
        self._client_now: aiomqtt.Client | None = None  # while subscribed: commands go here
        self._waiting: dict[str, asyncio.Future[Reply]] = {}
        self._sent = 0

    async def run(self, stop: asyncio.Event, on_ready: Callable[[str], None]) -> None:
        """Bind, tell `on_ready` the page's URL, follow the broker until `stop`; a bind
        that fails or a broker refusing the credentials is a one-line error."""
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
        follower = asyncio.create_task(self._follow())
        stopped = asyncio.create_task(stop.wait())
        on_ready(self.url)
        try:
            await asyncio.wait({follower, stopped}, return_when=asyncio.FIRST_COMPLETED)
            if follower.done():
                follower.result()  # a refusal at start: raised to the caller
        finally:
            stop.set()
            for task in (follower, stopped):
                task.cancel()
            await asyncio.gather(follower, stopped, return_exceptions=True)
            server.close()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(server.wait_closed(), 2.0)

    # -- MQTT ---------------------------------------------------------------------------------
    async def _follow(self) -> None:
        delay = BACKOFF_MIN_S
        ever_up = False
        reported = ""
        while True:
            try:
                async with self._client() as client:
                    await client.subscribe(self.topic, qos=1)
                    self.state.broker_up(self.clock())
                    ever_up, delay = True, BACKOFF_MIN_S
                    self.log(f"view: subscribed to {self.topic} on {self.broker.display}")
                    reported = ""
                    self._client_now = client
                    try:
                        async for message in client.messages:
                            topic, payload = message.topic.value, message.payload
                            if self._waiting:
                                self._take_reply(topic, payload)
                            self.state.feed(topic, payload, self.clock())
                    finally:
                        self._client_now = None
            except aiomqtt.MqttError as exc:
                why = str(exc) or type(exc).__name__
                if not ever_up and isinstance(exc, aiomqtt.MqttCodeError):
                    raise BrokerError(
                        f"{self.broker.display} refused the connection: {why}"
                    ) from None
                self.state.broker_down(self.clock(), why)
                if why != reported:
                    self.log(f"view: broker {self.broker.display} away ({why}); retrying")
                    reported = why
            await asyncio.sleep(delay * random.uniform(0.8, 1.0))
            delay = min(BACKOFF_MAX_S, delay * 2)

    def _take_reply(self, topic: str, payload: bytes) -> None:
        """A reply to a command this view sent: to the request waiting for it."""
        levels = topic.split("/")
        if len(levels) != 4 or levels[2] != "reply":
            return
        reply = read_reply(payload)
        if reply is None:
            return
        waiting = self._waiting.get(reply.id)
        if waiting is not None and not waiting.done():
            waiting.set_result(reply)

    async def _send(self, body: bytes) -> dict[str, object]:
        """Check one command from the page, publish it, wait for the gateway's reply: what
        the page shows (`accepted`, `detail`, and `by`: who answered)."""
        self._sent += 1
        request_id = f"view-{os.getpid()}-{self._sent}"
        try:
            out = prepare(body, request_id, self.state.gateway_id)
        except CommandRefused as exc:
            return {"command": None, "accepted": False, "by": "view", "detail": str(exc)}
        answer: dict[str, object] = {"command": out.name, "accepted": False, "by": "view"}
        client = self._client_now
        if client is None:
            return {**answer, "detail": "not sent: the broker is away"}
        if len(self._waiting) >= MAX_PENDING:
            return {**answer, "detail": f"not sent: {MAX_PENDING} commands await replies"}
        waiting: asyncio.Future[Reply] = asyncio.get_running_loop().create_future()
        self._waiting[out.id] = waiting
        try:
            await client.publish(out.topic, out.payload, qos=1, timeout=REPLY_TIMEOUT_S)
            self.log(f"view: sent {out.name} to {out.gateway} ({out.id})")
            reply = await asyncio.wait_for(waiting, REPLY_TIMEOUT_S)
        except aiomqtt.MqttError as exc:
            return {**answer, "detail": f"not sent: {str(exc) or type(exc).__name__}"}
        except TimeoutError:
            return {
                **answer,
                "detail": f"sent, no reply from {out.gateway} within {REPLY_TIMEOUT_S:g} s "
                f"(gateway away, or the broker user may not write {out.topic}?)",
            }
        finally:
            del self._waiting[out.id]
        return {**reply.as_dict(), "by": "gateway"}

    def _client(self) -> aiomqtt.Client:
        return aiomqtt.Client(
            self.broker.host,
            self.broker.port,
            username=self.broker.username,
            password=self.broker.password,
            identifier=f"grasplink-view-{os.getpid()}-{random.getrandbits(32):08x}",
            keepalive=self.broker.keepalive_s,
            tls_context=self.tls,
            timeout=CONNECT_TIMEOUT_S,
            logger=MQTT_LOGGER,
            protocol=aiomqtt.ProtocolVersion.V5,
            clean_start=True,
        )

    # -- HTTP ---------------------------------------------------------------------------------
    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            try:
                head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HEAD_TIMEOUT_S)
                request = parse_head(head)
            except asyncio.LimitOverrunError:
                raise HttpError(431, "request head too large") from None
            response = respond(request, self._hosts, self._files, self.tokens)
            head_only = request.method == "HEAD"
            if response.command:
                length = request.content_length or 0
                body = await asyncio.wait_for(reader.readexactly(length), HEAD_TIMEOUT_S)
                answer = json.dumps(await self._send(body)).encode()
                writer.write(encode(Response(200, answer, "application/json")))
                await writer.drain()
            elif response.events and not head_only:
                await self._stream(writer)
            else:
                writer.write(encode(response, head_only=head_only))
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

    async def _stream(self, writer: asyncio.StreamWriter) -> None:
        """One page's event stream: a frame every PUSH_S, the points since the last."""
        if self.pages >= MAX_PAGES:
            raise HttpError(503, f"{MAX_PAGES} pages open already")
        self.pages += 1
        try:
            writer.write(encode_head(Response(200, content_type="text/event-stream", events=True)))
            writer.write(f"retry: {RETRY_MS}\n\n".encode())
            cursor: int | None = None
            while not self._stop.is_set():
                frame, cursor = self.state.frame(self.clock(), cursor)
                data = json.dumps(frame, separators=(",", ":"), allow_nan=False)
                writer.write(f"data: {data}\n\n".encode())
                await asyncio.wait_for(writer.drain(), SEND_TIMEOUT_S)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._stop.wait(), PUSH_S)
        finally:
            self.pages -= 1


def serve(
    broker: BrokerUrl,
    http: HttpAddress,
    *,
    gateway_id: str | None = None,
    tls: ssl.SSLContext | None = None,
    allow_commands: bool = False,
    duration_s: float | None = None,
    log: Log = print,
    stop: Callable[[], bool] = lambda: False,
) -> None:
    """Run the view until `duration_s` passed or `stop()` says so (looked at every 0.2 s)."""

    async def main() -> None:
        done = asyncio.Event()
        view = LiveView(
            broker, http, gateway_id=gateway_id, tls=tls, allow_commands=allow_commands, log=log
        )
        end = None if duration_s is None else time.monotonic() + duration_s

        async def watch() -> None:
            while not done.is_set():
                if stop() or (end is not None and time.monotonic() >= end):
                    done.set()
                await asyncio.sleep(0.2)

        watcher = asyncio.create_task(watch())
        try:
            mode = "commands allowed" if allow_commands else "read-only"
            await view.run(done, lambda url: log(f"view: {url} (broker {broker.display}, {mode})"))
        finally:
            watcher.cancel()
            await asyncio.gather(watcher, return_exceptions=True)

    asyncio.run(main())
