"""Which alerts the machines' states and the jobs' ends raise: one per episode
(docs/server.md#alerts).

An episode of a rule on a machine starts when its condition starts (the machine is seen in
alarm, stopped or offline) and ends when a reading says otherwise. It raises one alert once
the condition has lasted the rule's ``minutes``, and, if the rule asks, one more when it ends;
nothing in between, however many status polls repeat the condition. A stop that ends before
its minutes raise nothing. A failed job is an episode of its own.

For the alarm and stopped rules a machine that is offline, or whose control does not say what
it does (``unknown``), neither starts nor ends an episode: a link that drops during a long stop
is not the stop's end, and would otherwise send the stop's message again when the link is back.

The engine is plain synchronous code with the time passed in (``now``), so a test drives it
through hours of a shop in a moment; :mod:`opendnc.server.alerts.component` feeds it from the event
bus.

Whether an episode's alert went out already is the database's to say (``alert_episodes``: a
restarted server, or the next server of a cluster, must not send it again), so the engine
also keeps which (rule, machine) the database may hold a fired episode of, and hands out
(:meth:`AlertEngine.take_ended`) those whose condition no longer holds: the alerts component
deletes their rows and sends the "cleared" alerts the deleted rows call for.
"""

from __future__ import annotations

import enum
from collections import deque
from dataclasses import dataclass
from datetime import datetime

from opendnc.server.config.alerts import AlertKind, AlertRule
from opendnc.server.core.events import JobFinished, LeaseChanged, MachineStatusChanged
from opendnc.server.core.state import State

__all__ = ["Alert", "AlertEngine", "Phase"]

# Job outcomes a supervisor hears about: a cancel is someone's decision, a retry not an end.
FAILED_OUTCOMES = frozenset({"failed", "interrupted"})
_STATE_OF = {AlertKind.ALARM: State.ALARM, AlertKind.STOPPED: State.STOPPED}
_UNDECIDED = frozenset({State.OFFLINE, State.UNKNOWN, State.NO_RECORD})


class Phase(enum.StrEnum):
    """Whether an alert says a condition began or ended."""

    FIRED = "fired"
    CLEARED = "cleared"


@dataclass(frozen=True)
class Alert:
    """One alert to send: which rule, which machine, what happened and since when (UTC)."""

    rule: AlertRule
    phase: Phase
    machine: str
    since: datetime  # when the condition began (the job's end for a failed job)
    at: datetime  # when the alert was raised
    detail: str = ""  # the alarm's text, the job's error, the link's last error
    job_id: int | None = None
    program: str | None = None

    @property
    def kind(self) -> AlertKind:
        """What the rule watches for."""
        return self.rule.kind


@dataclass
class _Episode:
    since: datetime
    detail: str
    fired: bool = False


class AlertEngine:
    """The open episodes of every rule on every machine; returns the alerts to send."""

    def __init__(self, rules: tuple[AlertRule, ...], *, remember_jobs: int = 1000) -> None:
        self.rules = rules
        self._episodes: dict[tuple[str, str], _Episode] = {}
        # a job's end can be published twice (a hand-back after an outage): one alert a job
        self._jobs: deque[int] = deque(maxlen=remember_jobs)
        self._elsewhere: set[str] = set()  # machines whose lease this server lost
        # (rule, machine) the database may hold a fired episode of; until seeded from it,
        # every key of a machine is such a key from the machine's first reading
        self._maybe_stored: set[tuple[str, str]] = set()
        self._seeded = False
        self._seen: set[str] = set()
        self._ended: list[tuple[str, str]] = []

    def seed(self, stored: set[tuple[str, str]]) -> None:
        """The (rule, machine) of the fired episodes the database holds now (at start)."""
        self._maybe_stored |= stored
        self._seeded = True

    def maybe_stored(self, key: tuple[str, str]) -> None:
        """The database may hold a fired episode of ``key`` (its row could not be deleted):
        it is handed out again at the next reading where its condition does not hold."""
        self._maybe_stored.add(key)

    def take_ended(self) -> list[tuple[str, str]]:
        """(rule, machine) whose condition ended or was seen not to hold while the database
        may hold a fired episode of it; each once."""
        ended, self._ended = self._ended, []
        return ended

    def _all_keys(self, machine: str) -> None:
        for rule in self.rules:
            if rule.kind is not AlertKind.JOB_FAILED and rule.applies_to(machine):
                self._maybe_stored.add((rule.name, machine))

    def _end(self, key: tuple[str, str]) -> None:
        if key in self._maybe_stored:
            self._maybe_stored.discard(key)
            self._ended.append(key)

    def lease(self, event: LeaseChanged) -> None:
        """This server gained or lost a machine (several servers): a lost one's episodes go
        (its new server alerts for it), and the offline reading its task's end leaves is not
        an outage."""
        if event.held:
            self._elsewhere.discard(event.machine)
            self._all_keys(event.machine)  # the server it came from may have stored some
        else:
            self._elsewhere.add(event.machine)
            self._forget(event.machine)

    def _forget(self, machine: str) -> None:
        for key in [k for k in self._episodes if k[1] == machine]:
            del self._episodes[key]

    def open_episodes(self) -> dict[tuple[str, str], datetime]:
        """(rule, machine) of every open episode, and since when."""
        return {key: episode.since for key, episode in self._episodes.items()}

    def status(self, event: MachineStatusChanged, now: datetime) -> list[Alert]:
        """A machine's reading: episodes start, fire or end."""
        machine = event.machine
        if not event.served or machine in self._elsewhere:
            # another server of the cluster serves it now: its alerts are that server's
            self._forget(machine)
            return []
        state = event.state
        if not self._seeded and machine not in self._seen:
            self._seen.add(machine)
            self._all_keys(machine)
        out: list[Alert] = []
        for rule in self.rules:
            if rule.kind is AlertKind.JOB_FAILED or not rule.applies_to(machine):
                continue
            holds = _holds(rule.kind, state)
            if holds is not None:
                out.extend(self._step(rule, event, holds, now))
        return out

    def _step(
        self, rule: AlertRule, event: MachineStatusChanged, holds: bool, now: datetime
    ) -> list[Alert]:
        """One rule's episode on a machine's reading whose condition ``holds`` or not: it
        starts, takes the newest detail until it fires, fires when due, or ends."""
        machine = event.machine
        key = (rule.name, machine)
        episode = self._episodes.get(key)
        if holds and episode is None:
            episode = self._episodes[key] = _Episode(now, _detail(rule.kind, event))
        elif holds and episode is not None and not episode.fired:
            episode.detail = _detail(rule.kind, event) or episode.detail
        elif not holds and episode is not None:
            del self._episodes[key]
            self._end(key)
            if episode.fired and rule.on_clear:
                return [Alert(rule, Phase.CLEARED, machine, episode.since, now)]
            return []
        elif not holds:
            self._end(key)
        if episode is None:
            return []
        return self._due(rule, machine, episode, now)

    def job(self, event: JobFinished, now: datetime) -> list[Alert]:
        """A job's end: a failed one raises its alert, once."""
        if event.outcome not in FAILED_OUTCOMES or event.job_id in self._jobs:
            return []
        self._jobs.append(event.job_id)
        return [
            Alert(
                rule,
                Phase.FIRED,
                event.machine,
                now,
                now,
                event.error or event.outcome,
                event.job_id,
                event.program,
            )
            for rule in self.rules
            if rule.kind is AlertKind.JOB_FAILED and rule.applies_to(event.machine)
        ]

    def tick(self, now: datetime) -> list[Alert]:
        """The episodes whose minutes are up by ``now`` (called every few seconds)."""
        rules = {rule.name: rule for rule in self.rules}
        out: list[Alert] = []
        for (name, machine), episode in self._episodes.items():
            out.extend(self._due(rules[name], machine, episode, now))
        return out

    def _due(self, rule: AlertRule, machine: str, episode: _Episode, now: datetime) -> list[Alert]:
        if episode.fired or (now - episode.since).total_seconds() < rule.minutes * 60:
            return []
        episode.fired = True
        self._maybe_stored.add((rule.name, machine))  # its row is written as it is sent
        return [Alert(rule, Phase.FIRED, machine, episode.since, now, episode.detail)]


def _holds(kind: AlertKind, state: State) -> bool | None:
    """Whether a reading in ``state`` meets a rule of ``kind``; ``None`` when the reading
    cannot tell (an undecided state neither starts nor ends an episode)."""
    if kind is AlertKind.OFFLINE:
        return state is State.OFFLINE
    if state in _UNDECIDED:
        return None
    return state is _STATE_OF[kind]


def _detail(kind: AlertKind, event: MachineStatusChanged) -> str:
    """What the control said about the condition, in one line."""
    status = event.status
    if kind is AlertKind.OFFLINE:
        return event.last_error
    if status is None:
        return ""
    if kind is AlertKind.ALARM:
        return "; ".join(status.errors)
    parts = [status.execution]
    if status.program:
        parts.append(f"program {status.program}")
    if status.line:
        parts.append(f"line {status.line}")
    return ", ".join(parts)
