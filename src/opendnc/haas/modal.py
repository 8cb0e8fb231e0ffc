"""Modal state of a Haas (Fanuc-style) program, for restarting a drip-feed mid-program.

A DNC restart at line N cannot just send lines N..end: the blocks before N set modes that the
rest of the program relies on (units, plane, absolute/incremental, work offset, tool, spindle,
coolant, feed). :func:`track` folds one program line into a :class:`ModalState`; it is pure, so
``functools.reduce(track, lines, ModalState())`` gives the state in force before line N.
:func:`restart_preamble` turns that state into the blocks re-sent before line N.

What the preamble re-sends, in this order (only what the program had set):

1. ``%`` and the program's ``O`` line as written (header, e.g. ``O01000 (PART)``);
2. ``(OPENDNC RESTART AT LINE n)``;
3. units ``G20``/``G21`` on their own line (they must precede any dimension);
4. a safety block ``G00 G17|G18|G19 G40 G80 G90``: rapid, plane, cutter compensation and canned
   cycles cancelled, absolute;
5. if ``retract`` is on (default), ``G91 G28 Z0.`` then ``G90``: Z to its home before anything
   moves in X/Y, as Haas programs do before a tool change;
6. the last tool change ``T.. M06``;
7. the work offset ``G54``..``G59``, ``G110``..``G129`` or ``G154 P..``;
8. tool length compensation ``G43 H..``/``G44 H..`` if it was active;
9. spindle ``S.. M03``/``S.. M04`` (or just ``S..`` when stopped);
10. coolant ``M07``/``M08`` and through-spindle coolant ``M88`` if on;
11. feed mode ``G93``/``G95`` if not the default ``G94``, ``G91`` if the program was
    incremental;
12. motion mode ``G00``/``G01`` with the last feed ``F..``.

An arc (``G02``/``G03``) or canned cycle in force at line N is not re-created (its parameters
live in the blocks before N): :attr:`RestartPlan.warnings` says so and line N should then be
chosen where a new move starts. Macro variables set before N are not re-created either.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field, replace

_COMMENT = re.compile(r"\([^)]*\)?")
# a word: letter + number or a plain variable (S#100); expressions in [] are left alone
_WORD = re.compile(r"([A-Z])\s*([-+]?(?:\d+\.?\d*|\.\d+)|#\d+)")
_LINE_END = re.compile(r"[\r\n]+")
_O_LINE = re.compile(r"^\s*[O:]\d{1,5}", re.IGNORECASE)
_MACRO_START = ("#", "IF", "WHILE", "END", "GOTO", "DPRNT", "POPEN", "PCLOS")

_UNITS = {20, 21}
_PLANES = {17, 18, 19}
_DISTANCE = {90, 91}
_MOTION = {0, 1, 2, 3}
_CYCLES = set(range(73, 90)) - {80}
_FEED_MODES = {93, 94, 95}


@dataclass(frozen=True, slots=True)
class ModalState:
    """Modes in force after the lines seen so far; ``None`` = never set by the program.

    Code-valued fields hold normalised codes (``"G21"``, ``"M03"``); word-valued fields keep
    the text as written (``"S1200"``, ``"F250."``) so it is re-sent unchanged.
    """

    header: str | None = None  # the O line as written
    units: str | None = None
    plane: str | None = None
    distance: str | None = None
    work_offset: str | None = None  # "G54" .. "G59", "G110".."G129", "G154 P3"
    motion: str | None = None  # G00..G03, or a canned cycle G73..G89
    feed_mode: str | None = None
    tool_length: str | None = None  # "G43 H5", "G44 H2"; None after G49
    tool: str | None = None  # "T5" of the last M06
    next_tool: str | None = None  # last T word, loaded by the next M06
    speed: str | None = None
    spindle: str | None = None  # M03, M04, M05
    coolant: str | None = None  # M07, M08, M09
    through_coolant: bool = False  # M88 on, M89 off
    feed: str | None = None


def _code(letter: str, value: float) -> str:
    whole = int(value)
    if value == whole:
        return f"{letter}{whole:02d}"
    return f"{letter}{value:g}"


def code_text(line: str) -> str:
    """The code part of a line: comments, a trailing ``;`` and block delete removed, upper case."""
    text = _COMMENT.sub(" ", line).upper().split(";", 1)[0].strip()
    return text[1:].lstrip() if text.startswith("/") else text


def track(state: ModalState, line: str) -> ModalState:
    """The state after executing ``line`` (pure; unknown or macro lines change nothing)."""
    text = code_text(line)
    if not text or text == "%":
        return state
    if state.header is None and _O_LINE.match(text):
        # a stray line end inside the line must not split the re-sent header block
        return replace(state, header=_LINE_END.sub(" ", line).strip())
    if text.startswith(_MACRO_START) or "=" in text:
        return state
    words = _WORD.findall(text)
    if not words:
        return state
    changes: dict[str, object] = {}
    singles: dict[str, str] = {}
    g_codes: list[float] = []
    m_codes: list[int] = []
    for letter, value in words:
        if letter == "G" and not value.startswith("#"):
            g_codes.append(float(value))
        elif letter == "M" and not value.startswith("#"):
            m_codes.append(round(float(value)))
        else:
            singles.setdefault(letter, f"{letter}{value}")
    for code in g_codes:
        number = round(code)
        if code != number:
            continue  # G-codes with a decimal (G187.x...) belong to no group tracked here
        if number in _UNITS:
            changes["units"] = _code("G", number)
        elif number in _PLANES:
            changes["plane"] = _code("G", number)
        elif number in _DISTANCE:
            changes["distance"] = _code("G", number)
        elif 54 <= number <= 59 or 110 <= number <= 129:
            changes["work_offset"] = _code("G", number)
        elif number == 154:
            changes["work_offset"] = "G154 " + singles.get("P", "P1")
        elif number in _MOTION or number in _CYCLES:
            changes["motion"] = _code("G", number)
        elif number == 80:
            changes["motion"] = None
        elif number in _FEED_MODES:
            changes["feed_mode"] = _code("G", number)
        elif number in (43, 44):
            changes["tool_length"] = _code("G", number) + (
                " " + singles["H"] if "H" in singles else ""
            )
        elif number == 49:
            changes["tool_length"] = None
    if "T" in singles:
        changes["next_tool"] = singles["T"]
    if "S" in singles:
        changes["speed"] = singles["S"]
    if "F" in singles:
        changes["feed"] = singles["F"]
    for m in m_codes:
        if m == 6:
            changes["tool"] = changes.get("next_tool", state.next_tool)
        elif m in (3, 4, 5):
            changes["spindle"] = _code("M", m)
        elif m in (7, 8, 9):
            changes["coolant"] = _code("M", m)
        elif m in (88, 89):
            changes["through_coolant"] = m == 88
    return replace(state, **changes) if changes else state  # type: ignore[arg-type]


def scan(lines: Iterable[str], state: ModalState | None = None) -> ModalState:
    """Fold every line of ``lines`` into ``state`` (default: nothing set)."""
    result = state or ModalState()
    for line in lines:
        result = track(result, line)
    return result


@dataclass(frozen=True, slots=True)
class RestartPlan:
    """The blocks to send before line ``line`` and what could not be restored."""

    line: int
    preamble: tuple[str, ...]
    warnings: tuple[str, ...] = field(default=())


def restart_preamble(state: ModalState, line: int, *, retract: bool = True) -> RestartPlan:
    """The blocks that restore ``state`` before restarting at (1-based) file line ``line``."""
    out: list[str] = ["%"]
    warnings: list[str] = []
    if state.header is not None:
        out.append(state.header)
    out.append(f"(OPENDNC RESTART AT LINE {line})")
    if state.units is not None:
        out.append(state.units)
    out.append(f"G00 {state.plane or 'G17'} G40 G80 G90")
    if retract:
        out += ["G91 G28 Z0.", "G90"]
    if state.tool is not None:
        out.append(f"{state.tool} M06")
    if state.work_offset is not None:
        out.append(state.work_offset)
    if state.tool_length is not None:
        out.append(state.tool_length)
    if state.spindle in ("M03", "M04"):
        out.append(f"{state.speed} {state.spindle}" if state.speed else state.spindle)
    elif state.speed is not None:
        out.append(state.speed)
    if state.coolant in ("M07", "M08"):
        out.append(state.coolant)
    if state.through_coolant:
        out.append("M88")
    if state.feed_mode in ("G93", "G95"):
        out.append(state.feed_mode)
    if state.distance == "G91":
        out.append("G91")
    motion = state.motion
    if motion in ("G00", "G01"):
        out.append(f"{motion} {state.feed}" if state.feed else motion)
    else:
        if state.feed is not None:
            out.append(state.feed)
        if motion is not None:
            warnings.append(
                f"{motion} was in force before line {line} and is not re-created; "
                "restart where a new move or cycle starts"
            )
    return RestartPlan(line, tuple(out), tuple(warnings))
