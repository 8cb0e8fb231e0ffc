"""The alerts component: watches the event bus, sends each alert to its targets, audits each
delivery (docs/server.md#alerts).

Nothing here can hold up a machine's task. The bus hands events over through a bounded
subscription (the oldest go when it is full); the watch task only runs the rules
(:mod:`opendnc.server.alerts.rules`) and puts alerts into one bounded outbox per target; each
target has its own task, so a dead SMTP server does not delay the webhooks, nor one webhook
another. SMTP runs in a thread of its own (smtplib blocks), never in the threads the server's
database work uses. A target that keeps failing is logged once when it goes down and once when
it is back, not once per message; every delivery, sent or failed, is one audit row
(``alert``, result ``ok`` or ``failed``, the target in ``detail``).

An episode's alert is sent once across restarts and across the servers of a cluster: the
``alert_episodes`` row is the claim. The server whose insert goes through sends the alert; one
that finds the row (it restarted, or took the machine over) does not. The server whose delete
takes the row when the condition ends sends the "cleared" alert, with the episode's first
``since``. A failed job's alerts are claimed the same way, one ``alerted_jobs`` row per job
(a job's end can be published by the server that ran it and again by one that took its
machine over or restarted). Both claims go through
:func:`~opendnc.server.store.claims.claim_once`: written before the alert is sent, so a
server killed mid-send leaves the claim and the alert is not sent again (at most once).
Without its database (an outage) an alert is sent rather than lost; a failed job's claim is
written once the database answers again, so no other server sends that job's alert later.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

from sqlalchemy import delete, select
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.alerts.delivery import (
    AlertBody,
    DeliveryError,
    body_of,
    email_of,
    post_webhook,
    scrub,
    send_email,
)
from opendnc.server.alerts.rules import Alert, AlertEngine, Phase
from opendnc.server.config.alerts import (
    AlertKind,
    AlertRule,
    AlertsConfig,
    EmailTarget,
    WebhookTarget,
)
from opendnc.server.core.components import cancel_and_wait
from opendnc.server.core.configkeys import ConfigError
from opendnc.server.core.events import (
    EventBus,
    JobFinished,
    LeaseChanged,
    MachineStatusChanged,
    Subscription,
)
from opendnc.server.core.shifts import Calendar
from opendnc.server.store import audit
from opendnc.server.store.claims import claim_once
from opendnc.server.store.models import AlertedJob, AlertEpisode

if TYPE_CHECKING:
    import httpx

__all__ = ["ACTION", "Alerts", "Delivery"]

log = logging.getLogger(__name__)

ACTION = "alert"  # the audit rows' action
ACTOR = "alerts"
TICK = 1.0  # seconds between checks of the rules' minutes
CLAIM_RETRY = 30.0  # seconds between tries to write the claims of jobs alerted in an outage


@dataclass(frozen=True)
class Delivery:
    """How one alert went to one target."""

    alert: Alert
    body: AlertBody
    target: str  # the target as the audit names it
    error: str = ""  # empty: sent
    attempts: int = 1

    @property
    def sent(self) -> bool:
        """True if the target took the alert."""
        return not self.error


def _now() -> datetime:
    return datetime.now(UTC)


class _Outbox:
    """A target's alerts waiting to go: bounded, the oldest dropped when full."""

    def __init__(self, size: int) -> None:
        self.items: deque[Alert] = deque(maxlen=size)
        self.ready = asyncio.Event()
        self.dropped = 0

    def put(self, alert: Alert) -> bool:
        """Queue ``alert``; False if the oldest one was dropped for it."""
        full = len(self.items) == self.items.maxlen
        if full:
            self.dropped += 1
        self.items.append(alert)
        self.ready.set()
        return not full

    async def get(self) -> Alert:
        while not self.items:
            self.ready.clear()
            await self.ready.wait()
        return self.items.popleft()


class Alerts:
    """Rules from ``[alerts]`` on the bus's events; deliveries to e-mail and webhooks."""

    name = "alerts"
    needs = ("machines", "database")

    def __init__(
        self,
        config: AlertsConfig,
        bus: EventBus,
        sessions: sessionmaker[Session] | None,
        calendar: Calendar,
        server: str,
        *,
        tick: float = TICK,
        clock: Callable[[], datetime] = _now,
    ) -> None:
        if config.webhooks:
            try:
                import httpx  # noqa: F401  (configured webhooks that cannot run fail at build)
            except ImportError:
                raise ConfigError(
                    "alerts.webhooks",
                    "needs httpx, part of the 'server' extra: pip install 'opendnc[server]'",
                ) from None
        self.config = config
        self.bus = bus
        self.sessions = sessions
        self.calendar = calendar
        self.server = server
        self.tick = tick
        self.clock = clock
        self.engine = AlertEngine(config.rules)
        self.outboxes = {t.name: _Outbox(config.queue) for t in config.targets}
        self.down: dict[str, bool] = {t.name: False for t in config.targets}
        self._client: httpx.AsyncClient | None = None
        self._stack = contextlib.ExitStack()
        self._tasks: list[asyncio.Task[None]] = []
        self._unstored: set[tuple[str, str]] = set()  # fired during an outage: no row
        self._store_down = False
        # failed jobs alerted while the database was away: job id -> (machine, when)
        self._unclaimed: dict[int, tuple[str, datetime]] = {}
        self._claim_retry = 0.0  # monotonic: when to try writing them again

    async def start(self) -> None:
        """Read the fired episodes from the database, subscribe to the bus, start the watch
        task and one task per target."""
        if self.sessions is not None:
            try:
                self.engine.seed(await asyncio.to_thread(_stored_episodes, self.sessions))
            except SQLAlchemyError as exc:  # each machine's keys are checked as it is seen
                log.warning("alerts: the fired episodes could not be read: %s", type(exc).__name__)
        self._open()
        subscription = self._stack.enter_context(self.bus.subscribe(maxsize=1000))
        self._tasks.append(asyncio.create_task(self._watch(subscription), name="alerts"))
        for target in self.config.targets:
            task = asyncio.create_task(self._send_loop(target), name=f"alerts-{target.name}")
            self._tasks.append(task)

    async def stop(self) -> None:
        """Stop the tasks (alerts not yet sent are dropped) and close the links."""
        tasks, self._tasks = self._tasks, []
        await cancel_and_wait(*tasks)
        self._stack.close()
        await self._close()

    def _open(self) -> None:
        if self.config.webhooks:
            import httpx

            # no connection pool kept across alerts: minutes apart, a kept one is stale
            limits = httpx.Limits(max_keepalive_connections=0)
            self._client = httpx.AsyncClient(limits=limits, follow_redirects=False)

    async def _close(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            await client.aclose()

    async def send_test(self, machine: str, names: tuple[str, ...] = ()) -> list[Delivery]:
        """Send one test alert ("machine in alarm") to each target of ``names`` (every one
        when empty), one after the other, and say how each went (``opendnc alerts test``; not
        audited, and not for a running component)."""
        now = self.clock()
        rule = AlertRule("test", AlertKind.ALARM)
        alert = Alert(rule, Phase.FIRED, machine, now, now, "a test of the alerts (opendnc)")
        chosen = [t for t in self.config.targets if not names or t.name in names]
        self._open()
        try:
            return [await self.deliver(target, alert) for target in chosen]
        finally:
            await self._close()

    # -- watching -------------------------------------------------------------------------

    async def _watch(self, subscription: Subscription) -> None:
        while True:
            event = await subscription.get(timeout=self.tick)
            now = self.clock()
            try:
                if isinstance(event, MachineStatusChanged):
                    await self._settle(self.engine.status(event, now), now)
                elif isinstance(event, JobFinished):
                    await self._raise_job(self.engine.job(event, now), now)
                elif isinstance(event, LeaseChanged):
                    self.engine.lease(event)
                await self._settle(self.engine.tick(now), now)
                await self._write_unclaimed()
            except Exception:  # a bug in one rule must not end the watch for the others
                log.exception("alerts: an event could not be judged")
            if subscription.take_overflow():
                log.warning("alerts: events lost while the bus was busy; the next poll repeats")

    async def _raise_job(self, alerts: list[Alert], now: datetime) -> None:
        """Raise a failed job's ``alerts`` (one per rule) if this server claims the job: the
        one server whose ``alerted_jobs`` insert goes through sends them."""
        sessions = self.sessions
        if not alerts or sessions is None:
            self.raise_all(alerts)
            return
        first = alerts[0]
        if first.job_id is None:  # pragma: no cover - a JobFinished always names its job
            self.raise_all(alerts)
            return
        row = AlertedJob(
            job_id=first.job_id, machine=first.machine, server=self.server, claimed=now
        )
        try:
            mine = await asyncio.to_thread(claim_once, sessions, row)
        except SQLAlchemyError as exc:  # the database is away: a duplicate beats a lost alert
            if not self._store_down:
                log.warning("alerts: job %d's claim not stored (sent all the same): %s",
                            first.job_id, type(exc).__name__)  # fmt: skip
            self._store_down = True
            self._unclaimed[first.job_id] = (first.machine, now)
            self.raise_all(alerts)
            return
        if self._store_down:
            log.warning("alerts: claims are stored again")
            self._store_down = False
        if mine:
            self.raise_all(alerts)
        else:
            log.info("alerts: job %d's failure was alerted already; not sent again", first.job_id)

    async def _write_unclaimed(self) -> None:
        """Write the claims of the failed jobs alerted during an outage (every
        :data:`CLAIM_RETRY` seconds until the database takes them), so that no server alerts
        for them again. A claim found there already means another server sent one too."""
        sessions = self.sessions
        if not self._unclaimed or sessions is None or time.monotonic() < self._claim_retry:
            return
        self._claim_retry = time.monotonic() + CLAIM_RETRY
        for job_id, (machine, at) in list(self._unclaimed.items()):
            row = AlertedJob(job_id=job_id, machine=machine, server=self.server, claimed=at)
            try:
                await asyncio.to_thread(claim_once, sessions, row)
            except SQLAlchemyError:
                return  # still away: the next try is CLAIM_RETRY seconds on
            del self._unclaimed[job_id]

    async def _settle(self, alerts: list[Alert], now: datetime) -> None:
        """Raise ``alerts`` as the database's episodes allow (see the module docstring): an
        episode's alert only if this server claimed it, its end only if this server deleted
        its row (or sent it without one)."""
        ended = self.engine.take_ended()
        sessions = self.sessions
        if sessions is None:
            self.raise_all(alerts)
            return
        fired = [a for a in alerts if a.phase is Phase.FIRED]
        if not fired and not ended:
            self.raise_all([a for a in alerts if a.phase is not Phase.CLEARED])
            return
        try:
            claimed, deleted = await asyncio.to_thread(
                _claim_and_end, sessions, self.server, fired, ended
            )
        except SQLAlchemyError as exc:
            self._send_unstored(alerts, fired, ended, exc)
            return
        if self._store_down:
            log.warning("alerts: episodes are stored again")
            self._store_down = False
        self.raise_all(self._claimed(alerts, claimed, deleted, now))

    def _send_unstored(
        self,
        alerts: list[Alert],
        fired: list[Alert],
        ended: list[tuple[str, str]],
        exc: SQLAlchemyError,
    ) -> None:
        """The database is down: send the alerts all the same (a duplicate beats a lost
        alarm), and remember what fired unstored so that its end is sent without a row."""
        if not self._store_down:
            log.warning("alerts: episodes not stored (sent all the same): %s", exc)
        self._store_down = True
        for key in ended:
            self.engine.maybe_stored(key)  # its row is deleted at a later reading
        self._unstored |= {(a.rule.name, a.machine) for a in fired}
        self.raise_all([a for a in alerts if a.phase is not Phase.CLEARED])
        own_clears = {(a.rule.name, a.machine): a for a in alerts if a.phase is Phase.CLEARED}
        for key, clear in own_clears.items():
            if key in self._unstored:
                self._unstored.discard(key)
                self.raise_all([clear])

    def _claimed(
        self,
        alerts: list[Alert],
        claimed: set[tuple[str, str]],
        deleted: dict[tuple[str, str], datetime],
        now: datetime,
    ) -> list[Alert]:
        """What this server sends once the database answered: the episodes it claimed, ends
        of those that fired during an outage, and ends of the rows it deleted."""
        rules = {rule.name: rule for rule in self.config.rules}
        out: list[Alert] = []
        for alert in alerts:
            key = (alert.rule.name, alert.machine)
            if alert.phase is Phase.CLEARED:
                if key in self._unstored:  # it fired during an outage: no row to say so
                    self._unstored.discard(key)
                    out.append(alert)
            elif key in claimed:
                out.append(alert)
        for (name, machine), since in deleted.items():
            rule = rules.get(name)
            if rule is not None and rule.on_clear:
                out.append(Alert(rule, Phase.CLEARED, machine, since, now))
        return out

    def raise_all(self, alerts: list[Alert]) -> None:
        """Put each alert into the outbox of each of its rule's targets."""
        for alert in alerts:
            names = alert.rule.send_to or tuple(self.outboxes)
            for name in names:
                outbox = self.outboxes[name]
                if not outbox.put(alert) and outbox.dropped == 1:
                    log.warning("alerts: %s is behind; its oldest alerts are dropped", name)

    # -- sending --------------------------------------------------------------------------

    async def _send_loop(self, target: EmailTarget | WebhookTarget) -> None:
        outbox = self.outboxes[target.name]
        while True:
            alert = await outbox.get()
            delivery = await self.deliver(target, alert)
            self._note(target, delivery)
            await self._audit(delivery)

    async def deliver(self, target: EmailTarget | WebhookTarget, alert: Alert) -> Delivery:
        """Send ``alert`` to ``target``, with the target's retries and a doubling backoff."""
        body = body_of(alert, self.calendar, self.server, self.config.public_url)
        delay = self.config.backoff
        error = ""
        for attempt in range(1, target.retries + 2):
            try:
                await self._try(target, body)
                return Delivery(alert, body, target.describe(), attempts=attempt)
            except DeliveryError as exc:
                error = str(exc)
            except Exception as exc:  # a library's own error (a URL it refuses, ...): one line,
                # secrets out, and the target's task goes on with the next alert
                error = scrub(f"{type(exc).__name__}: {exc}", *_secrets(target))
            if attempt <= target.retries:
                await asyncio.sleep(delay)
                delay *= 2
        return Delivery(alert, body, target.describe(), error, target.retries + 1)

    async def _try(self, target: EmailTarget | WebhookTarget, body: AlertBody) -> None:
        if isinstance(target, EmailTarget):
            await _in_thread(send_email, target, email_of(body, target))
        else:
            assert self._client is not None
            await post_webhook(self._client, target, body.encode())

    def _note(self, target: EmailTarget | WebhookTarget, delivery: Delivery) -> None:
        """Log a target going down and coming back, once each (not once per message)."""
        was_down = self.down[target.name]
        if not delivery.sent and not was_down:
            log.warning("alerts: %s is not reachable: %s", delivery.target, delivery.error)
        elif delivery.sent and was_down:
            log.warning("alerts: %s is reachable again", delivery.target)
        self.down[target.name] = not delivery.sent

    async def _audit(self, delivery: Delivery) -> None:
        alert = delivery.alert
        sessions = self.sessions
        if sessions is None:  # a component built without a database audits nothing
            return

        extra: dict[str, Any] = {"error": delivery.error} if delivery.error else {}

        def write() -> None:
            with sessions.begin() as session:
                audit.record(
                    session,
                    ACTOR,
                    ACTION,
                    machine=alert.machine,
                    program=alert.program,
                    job_id=alert.job_id,
                    result="ok" if delivery.sent else "failed",
                    rule=alert.rule.name,
                    kind=alert.kind.value,
                    phase=alert.phase.value,
                    since=alert.since.isoformat(),
                    target=delivery.target,
                    attempts=delivery.attempts,
                    **extra,
                )

        try:
            await asyncio.to_thread(write)
        except SQLAlchemyError as exc:  # the database is away: the alert itself went (or not)
            log.warning("alerts: audit row not written: %s", type(exc).__name__)


def _stored_episodes(sessions: sessionmaker[Session]) -> set[tuple[str, str]]:
    with sessions() as session:
        rows = session.execute(select(AlertEpisode.rule, AlertEpisode.machine)).all()
        return {(rule, machine) for rule, machine in rows}


def _claim_and_end(
    sessions: sessionmaker[Session],
    server: str,
    fired: list[Alert],
    ended: list[tuple[str, str]],
) -> tuple[set[tuple[str, str]], dict[tuple[str, str], datetime]]:
    """Insert a row for each of ``fired`` (the keys whose insert went through: this server
    sends those) and delete the rows of ``ended`` (the keys deleted here, with the episode's
    ``since``: this server sends their ends). One transaction per claim: a claim another
    server made first refuses this one alone."""
    claimed: set[tuple[str, str]] = set()
    for alert in fired:
        row = AlertEpisode(
            rule=alert.rule.name,
            machine=alert.machine,
            since=alert.since,
            fired=alert.at,
            server=server,
            detail=alert.detail[:2000],
        )
        if claim_once(sessions, row):  # else sent already: before a restart, or elsewhere
            claimed.add((alert.rule.name, alert.machine))
    deleted: dict[tuple[str, str], datetime] = {}
    if ended:
        with sessions.begin() as session:
            for name, machine in ended:
                since = session.scalar(
                    delete(AlertEpisode)
                    .where(AlertEpisode.rule == name, AlertEpisode.machine == machine)
                    .returning(AlertEpisode.since)
                )
                if since is not None:
                    deleted[(name, machine)] = since
    return claimed, deleted


def _secrets(target: EmailTarget | WebhookTarget) -> tuple[str, ...]:
    """What no message about ``target`` may show."""
    if isinstance(target, EmailTarget):
        return (target.password,)
    return (target.url, target.secret)


async def _in_thread(function: Callable[..., None], *args: Any) -> None:
    """Run ``function(*args)`` in a daemon thread of its own and wait for it.

    Not the loop's default executor, whose threads the database work uses, nor an executor of
    our own: Python joins an executor's threads at exit, so an SMTP server that hangs would
    hold up the end of a stopped server for its whole timeout. A cancelled wait leaves the
    thread to end at its socket's timeout, unwaited for.
    """
    loop = asyncio.get_running_loop()
    done: asyncio.Future[None] = loop.create_future()

    def settle(error: BaseException | None) -> None:
        if done.done():
            return
        if error is None:
            done.set_result(None)
        else:
            done.set_exception(error)

    def run() -> None:
        error: BaseException | None = None
        try:
            function(*args)
        except BaseException as exc:  # handed to the waiting task, which decides
            error = exc
        with contextlib.suppress(RuntimeError):  # the loop closed meanwhile: nobody waits
            loop.call_soon_threadsafe(settle, error)

    threading.Thread(target=run, name="alerts-smtp", daemon=True).start()
    await done
