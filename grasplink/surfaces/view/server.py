"""The live view's edge: one asyncio loop holding the MQTT subscription (aiomqtt, public
API only) and a small HTTP server streaming frames to each page (Server-Sent Events).

Everything the page shows is `state.ViewState`'s; this module only moves bytes and
reads the clock. Read-only unless commands are allowed: then it publishes the commands
`commands.prepare` passed, and nothing else, and hands the page the gateway's reply.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import random
import ssl
import time
from collections.abc import Callable

import aiomqtt

from grasplink.errors import BrokerError
from grasplink.surfaces.telemetry.url import BrokerUrl
from grasplink.surfaces.view.commands import (
    REPLY_TIMEOUT_S,
    CommandRefused,
    Reply,
    Tokens,
    prepare,
    read_reply,
)
from grasplink.surfaces.view.pages import (
    HEAD_TIMEOUT_S,
    HttpAddress,
    Log,
    PageServer,
    parse_http_address,
    run_until,
)
from grasplink.surfaces.view.state import ROOT, ViewState
from grasplink.surfaces.view.web import (
    Request,
    Response,
    encode,
    load_files,
    respond,
)

__all__ = ["HttpAddress", "LiveView", "parse_http_address", "serve"]

CONNECT_TIMEOUT_S = 5.0
BACKOFF_MIN_S, BACKOFF_MAX_S = 0.5, 5.0  # short: the page shows the broker back soon
MAX_PENDING = 16  # commands waiting for their reply at once; more are answered 503
MQTT_LOGGER = logging.getLogger("grasplink.view.mqtt")
MQTT_LOGGER.addHandler(logging.NullHandler())


class LiveView(PageServer):
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
        super().__init__(http, clock)
        self.broker = broker
        self.tls = tls
        self.log = log
        self.state = ViewState(gateway_id)
        self.topic = f"{ROOT}/{gateway_id or '+'}/#"
        self._files = load_files()
        self.tokens = Tokens() if allow_commands else None
        self._client_now: aiomqtt.Client | None = None  # while subscribed: commands go here
        self._waiting: dict[str, asyncio.Future[Reply]] = {}
        self._sent = 0

    async def run(self, stop: asyncio.Event, on_ready: Callable[[str], None]) -> None:
        """Bind, tell `on_ready` the page's URL, follow the broker until `stop`; a bind
        that fails or a broker refusing the credentials is a one-line error."""
        async with self.bound(stop) as url:
            follower = asyncio.create_task(self._follow())
            stopped = asyncio.create_task(stop.wait())
            on_ready(url)
            try:
                await asyncio.wait({follower, stopped}, return_when=asyncio.FIRST_COMPLETED)
                if follower.done():
                    follower.result()  # a refusal at start: raised to the caller
            finally:
                stop.set()
                for task in (follower, stopped):
                    task.cancel()
                await asyncio.gather(follower, stopped, return_exceptions=True)

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
    async def handle(
        self, request: Request, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> None:
        response = respond(request, self._hosts, self._files, self.tokens)
        head_only = request.method == "HEAD"
        if response.command:
            length = request.content_length or 0
            body = await asyncio.wait_for(reader.readexactly(length), HEAD_TIMEOUT_S)
            answer = json.dumps(await self._send(body)).encode()
            writer.write(encode(Response(200, answer, "application/json")))
            await writer.drain()
        elif response.events and not head_only:
            cursor: int | None = None

            def frame() -> object:
                nonlocal cursor
                shown, cursor = self.state.frame(self.clock(), cursor)
                return shown

            await self.stream(writer, frame)
        else:
            writer.write(encode(response, head_only=head_only))
            await writer.drain()


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

    view = LiveView(
        broker, http, gateway_id=gateway_id, tls=tls, allow_commands=allow_commands, log=log
    )
    mode = "commands allowed" if allow_commands else "read-only"

    async def run(done: asyncio.Event) -> None:
        await view.run(done, lambda url: log(f"view: {url} (broker {broker.display}, {mode})"))

    run_until(run, duration_s, stop)
