"""The one place that decides what state a machine is in, from what its control reported.

Every consumer (the cards, the status timeline, utilization, MQTT, MTConnect) asks
:func:`classify` instead of reading ``execution`` itself, so a card, a timeline strip and a
utilization figure can never disagree about the same moment (docs/server.md#machine-status).

Two rules shops rely on, and which a naive reading gets wrong:

* a transfer is not the machine running: a program load into memory leaves the control
  ready, so only the control's own execution word says ``running``;
* a control that reports nothing is ``unknown``, not idle: a serial Haas without MDC can be
  reached, but nobody knows whether it cuts.
"""

from __future__ import annotations

from enum import StrEnum

from opendnc.server.core.status import MachineStatus

__all__ = ["State", "classify", "classify_words", "from_stored"]


class State(StrEnum):
    """A machine's state as people on the floor read it (andon colours in the dashboard)."""

    RUNNING = "running"  # the control executes a program (MTConnect EXECUTION ACTIVE)
    READY = "ready"  # reachable and idle: nothing runs, nothing holds
    STOPPED = "stopped"  # a program was stopped, interrupted or holds its feed
    ALARM = "alarm"  # the control reports an error or alarm
    OFFLINE = "offline"  # the server cannot reach the control
    UNKNOWN = "unknown"  # reachable, but the control does not say what it does
    NO_RECORD = "no_record"  # the server was not running: only in stored history


# MTConnect EXECUTION words, grouped by what they mean on the floor.
_RUNNING = frozenset({"ACTIVE"})
_STOPPED = frozenset({"STOPPED", "INTERRUPTED", "FEED_HOLD", "OPTIONAL_STOP", "PROGRAM_STOPPED"})
_READY = frozenset({"READY", "PROGRAM_COMPLETED", "WAIT"})


def classify_words(*, online: bool, execution: str, errors: bool) -> State:
    """The state of a control from its execution word and whether it reports errors."""
    if not online:
        return State.OFFLINE
    if errors:
        return State.ALARM
    word = execution.upper()
    if word in _RUNNING:
        return State.RUNNING
    if word in _STOPPED:
        return State.STOPPED
    if word in _READY:
        return State.READY
    return State.UNKNOWN  # UNAVAILABLE, empty, or a word we do not know


def classify(status: MachineStatus | None, *, online: bool) -> State:
    """The state of a machine: ``online`` is whether its link is up, ``status`` its last reading."""
    if status is None:
        return State.OFFLINE if not online else State.UNKNOWN
    return classify_words(
        online=online and status.available,
        execution=status.execution,
        errors=bool(status.errors),
    )


# What status samples written before the classifier said (docs/dashboard.md#status-timeline).
_OLD_WORDS = {"active": State.RUNNING, "none": State.NO_RECORD}


def from_stored(word: str, execution: str) -> State:
    """The state a stored status sample names, in today's words: the one reader of stored
    state words, for the status timeline and utilization alike (docs/server.md#status-samples).

    ``word`` is the sample's ``state`` column, ``execution`` the control's execution word
    stored beside it. Samples written before the one classifier said ``active`` (running) and
    ``none`` (no record); anything this server never wrote is unknown.
    """
    if word == State.READY.value:
        # Before the classifier, a reachable control that said no execution word at all (a
        # serial Haas without MDC) was filed as ``ready``; today that control is unknown, not
        # idle. The stored word was the old writer's reading; the execution word is what the
        # control itself said, so it decides. A sample written today reads the same either
        # way: the classifier writes ``ready`` only for an execution word that means ready.
        return classify_words(online=True, execution=execution, errors=False)
    try:
        return State(word)
    except ValueError:
        return _OLD_WORDS.get(word, State.UNKNOWN)
