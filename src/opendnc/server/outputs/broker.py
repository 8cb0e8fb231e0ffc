"""One MQTT link kept up with backoff: what the plain MQTT output and the Sparkplug B node
share (docs/server.md#mqtt, docs/server.md#sparkplug-b).

:class:`BrokerLink` makes the aiomqtt client (TLS, login, the last will, a 30 s keep-alive),
runs an output's session on each connection, says the output's last words on a clean stop
(bounded: a stop must not wait on a slow broker; the broker sends the will only when the link
dies), and connects again after 1 s, 2 s, ... up to 60 s. Each output keeps what it says and
when; the link keeps only the connection. aiomqtt is imported only when a link runs.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import ssl
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from opendnc.server.config.shop import MqttConfig

if TYPE_CHECKING:
    import aiomqtt

__all__ = ["STOP_SECONDS", "BrokerLink", "ReconnectNow", "Will"]

log = logging.getLogger(__name__)

STOP_SECONDS = 2.0
"""How long a clean stop may take to say an output's last words (whatever cancels it again)."""

Session = Callable[["aiomqtt.Client"], Awaitable[None]]


@dataclass(frozen=True)
class Will:
    """The message the broker publishes for a session that dies (MQTT's last will)."""

    topic: str
    payload: str | bytes
    qos: int = 1
    retain: bool = False


class ReconnectNow(Exception):
    """Raised by a session that ended itself (it said what it had to): connect again at once."""


class BrokerLink:
    """The connection of one output to its broker; :meth:`run` until cancelled."""

    def __init__(
        self,
        config: MqttConfig,
        identifier: str,
        label: str,
        *,
        clean_session: bool | None = None,
        min_backoff: float = 1.0,
        max_backoff: float = 60.0,
    ) -> None:
        self.config = config
        self.identifier = identifier
        self.label = label  # the output's name in the log ("mqtt", "sparkplug")
        self.clean_session = clean_session
        self.min_backoff = min_backoff
        self.max_backoff = max_backoff
        self.connected = False
        self.connects = 0

    @property
    def where(self) -> str:
        """``host:port`` of the broker."""
        return f"{self.config.host}:{self.config.port}"

    def client(self, will: Will) -> aiomqtt.Client:
        """A client for one session, with ``will`` as its last will."""
        import aiomqtt

        config = self.config
        tls_context = None
        if config.tls:
            cafile = str(config.ca_file) if config.ca_file else None
            tls_context = ssl.create_default_context(cafile=cafile)
        return aiomqtt.Client(
            config.host,
            config.port,
            username=config.username or None,
            password=config.password or None,
            identifier=self.identifier,
            will=aiomqtt.Will(will.topic, will.payload, qos=will.qos, retain=will.retain),
            clean_session=self.clean_session,
            tls_context=tls_context,
            timeout=10,
            keepalive=30,
        )

    async def _last_words(self, stopping: Session, client: aiomqtt.Client) -> None:
        """Run ``stopping(client)`` to its end or for :data:`STOP_SECONDS`, whichever comes
        first, whatever cancels arrive meanwhile: a stop repeats its cancel every half second
        (:func:`~opendnc.server.core.components.cancel_and_wait`), and one that cut the last words
        short would leave the broker saying what is no longer true (measured: 41 to 244 of 500
        machines left offline and the health left "true")."""
        loop = asyncio.get_running_loop()
        words = asyncio.ensure_future(stopping(client))
        end = loop.time() + STOP_SECONDS
        while not words.done():
            left = end - loop.time()
            if left <= 0:
                log.warning("%s: the last words took more than %.0f s; cut", self.label,
                            STOP_SECONDS)  # fmt: skip
                words.cancel()
                break
            try:
                await asyncio.wait({words}, timeout=left)
            except asyncio.CancelledError:
                continue  # the stop again: the words go on, within their own bound
        # Its error (a broken link) or its cancel ends nothing more here, and a cancel it
        # swallows (a client's wait for an acknowledgement can) never holds the stop: one
        # second more at most.
        with contextlib.suppress(Exception, asyncio.CancelledError):
            await asyncio.wait({words}, timeout=1.0)
        if words.done() and not words.cancelled():
            words.exception()  # retrieved: a broken link's error is not reported again

    async def run(
        self,
        session: Session,
        will: Callable[[], Will],
        *,
        stopping: Session | None = None,
        before: Callable[[], Awaitable[None]] | None = None,
        after: Callable[[], None] | None = None,
    ) -> None:
        """Connect, run ``session(client)`` until the link breaks, and again, until cancelled.

        ``before`` runs ahead of each connection (``will()`` is read after it), ``after``
        once each session has ended however it ended; ``stopping(client)`` says the output's
        last words when the link is cancelled (a clean stop), within :data:`STOP_SECONDS`.
        """
        import aiomqtt

        backoff = self.min_backoff
        while True:
            if before is not None:
                await before()
            try:
                async with self.client(will()) as client:
                    self.connected = True
                    self.connects += 1
                    backoff = self.min_backoff
                    log.info("%s: connected to %s", self.label, self.where)
                    try:
                        await session(client)
                    except asyncio.CancelledError:
                        if stopping is not None:
                            await self._last_words(stopping, client)
                        raise
            except ReconnectNow:
                backoff = 0.0
            except (aiomqtt.MqttError, OSError) as exc:
                log.warning("%s: %s: %s; again in %.0f s", self.label, self.where, exc, backoff)
            except Exception:  # a bug in one session must not end the output for good
                log.exception("%s: the session ended by an error; again in %.0f s", self.label,
                              backoff)  # fmt: skip
            finally:
                self.connected = False
                if after is not None:
                    after()
            await asyncio.sleep(backoff)
            backoff = min(max(backoff, self.min_backoff) * 2, self.max_backoff)
