"""G-code dialects as data: what one control (Haas or Fanuc, mill or lathe) accepts.

A :class:`Dialect` names a control's G and M codes, whether it turns (lathe: X is a
diameter, U/W are incremental X/Z, G96/G97/G50 spindle, G70-G76 cycles), which M codes
stop the spindle, which system variables a program may write although the shared variable
table keeps them read-only, and the number range of its programmed alarms. The dry run of
:mod:`opendnc.nccheck.gcode` reads only this record, so a new control is a new entry in
:data:`DIALECTS` (docs/check.md#dialects).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from opendnc.errors import InputError
from opendnc.nccheck import codes

__all__ = ["DIALECTS", "Dialect", "dialect_named", "guess_dialect", "lathe_word"]


@dataclass(frozen=True)
class Dialect:
    """One G-code control's language, as far as the dry run needs it."""

    name: str
    """``haas-mill``, ``haas-lathe``, ``fanuc-mill``, ``fanuc-lathe`` (or a guessed mix)."""
    title: str
    """For messages: ``Haas lathe``."""
    lathe: bool
    g_codes: frozenset[float]
    m_codes: frozenset[float]
    m_from: int | None = 100
    """Every M code from this number up is accepted (options and user M codes; None: none)."""
    haas: bool = True
    """Haas only: M97 local sub-programs, G154 P work offsets, the 1000+n alarm numbers."""
    fanuc: bool = True
    """Fanuc: M29 rigid tapping, G54.1 Pn work offsets, 3000+n alarm numbers."""
    spindle_stops: frozenset[int] = frozenset((5, 6))
    """M codes after which the spindle is stopped: M05 and a tool change (M06: Haas and Fanuc
    mills orient and stop the spindle to change the tool). M00/M01 are left out: whether the
    spindle stops there is the machine builder's choice."""
    writable: frozenset[int] = frozenset((3001, 3002))
    """System variables a program may write: the millisecond and hour timers (reset)."""
    rigid_tap_m: int | None = 29
    """The M code that puts the next G84 in rigid mode (the cycle turns the spindle)."""
    tap_starts_spindle: bool = False
    """G84 starts the spindle itself, so a tap with the spindle stopped is no fault (Haas:
    "It is not necessary to start the spindle CW before this canned cycle")."""
    dwell_ms: bool = True
    """A dwell's P written without a decimal point (``G04 P500``, a drilling cycle's P) counts
    milliseconds, with one (``P0.5``) seconds: Haas and Fanuc (docs/check.md#decimal-point)."""
    bare_letters: str = "XYZUVWIJKR"
    """Words whose number, written without a decimal point, counts in the least input
    increment, 0.001 mm or 0.0001 inch (``X100`` is 0.1 mm): the power-on default of Fanuc
    (parameter 3401#0 DPI = 0) and Haas (setting 162 off); empty where whole numbers mean mm
    or inches (DPI = 1, setting 162 on). docs/check.md#decimal-point."""

    @property
    def family(self) -> str:
        """``haas`` or ``fanuc`` (``haas`` for a guessed mix)."""
        return "haas" if self.haas else "fanuc"


# Haas also reads F without a point in the increment (setting 77 off, its default: F12 is
# 0.012 mm/min); Fanuc reads F300 as 300 mm/min
_HAAS_BARE = "XYZUVWIJKRF"
_HAAS_MILL = Dialect(
    "haas-mill", "Haas mill", False, codes.HAAS_MILL_G, codes.HAAS_M, fanuc=False,
    rigid_tap_m=None, tap_starts_spindle=True, bare_letters=_HAAS_BARE,
)  # fmt: skip
_FANUC_MILL = Dialect(
    "fanuc-mill", "Fanuc mill", False, codes.FANUC_MILL_G, codes.HAAS_M, m_from=0, haas=False
)
_HAAS_LATHE = Dialect(
    "haas-lathe", "Haas lathe", True, codes.HAAS_LATHE_G, codes.HAAS_LATHE_M, fanuc=False,
    rigid_tap_m=None, tap_starts_spindle=True, bare_letters=_HAAS_BARE,
)  # fmt: skip
_FANUC_LATHE = Dialect(
    "fanuc-lathe", "Fanuc lathe", True, codes.FANUC_LATHE_G, codes.HAAS_LATHE_M, m_from=0,
    haas=False,
)  # fmt: skip
# When no control is named: the union of Haas and Fanuc of the guessed kind, so that a code
# either control has is never reported (a false error blocks a release); the M codes too: a
# Fanuc takes every M code (the machine builder's), so the union does; and a tap with the
# spindle stopped runs on a Haas, so the union lets it pass
_MILL = Dialect(
    "mill", "Haas/Fanuc mill", False, codes.HAAS_G, codes.HAAS_M, m_from=_FANUC_MILL.m_from,
    tap_starts_spindle=True,
)  # fmt: skip
_LATHE = Dialect(
    "lathe",
    "Haas/Fanuc lathe",
    True,
    codes.HAAS_LATHE_G | codes.FANUC_LATHE_G,
    codes.HAAS_LATHE_M,
    m_from=_FANUC_LATHE.m_from,
    tap_starts_spindle=True,
)

DIALECTS: dict[str, Dialect] = {
    d.name: d for d in (_HAAS_MILL, _HAAS_LATHE, _FANUC_MILL, _FANUC_LATHE, _MILL, _LATHE)
}
"""Every dialect by name (``--control`` and the machine key ``control`` take these)."""

# Lathe-only words: constant surface speed, the spindle clamp, the lathe contour cycles
# (G71 with P and Q), incremental U/W moves. A mill program has none of them.
_LATHE_HINT = re.compile(
    r"^[^(\n]*?\b(?:G9[67]\b|G50\s*S|G7[0-3]\s*P\d|G0?[0-3]\s*[UW][-.\d])", re.MULTILINE
)


def guess_dialect(text: str) -> Dialect:
    """The dialect of a G-code program whose control is not named: a lathe when the text
    holds lathe-only words (G96/G97, G50 S, G71 P..), else a mill (Haas and Fanuc codes)."""
    return _LATHE if _LATHE_HINT.search(text, 0, 1 << 20) else _MILL


def lathe_word(text: str) -> tuple[int, str] | None:
    """The line (from 1) and text of the first lathe-only word in ``text`` (see
    :func:`guess_dialect`), or None."""
    match = _LATHE_HINT.search(text, 0, 1 << 20)
    if match is None:
        return None
    start = text.rfind("\n", 0, match.start()) + 1
    end = text.find("\n", match.end())
    block = text[start : end if end >= 0 else len(text)].strip()
    return text.count("\n", 0, match.start()) + 1, block[:40]


def dialect_named(name: str) -> Dialect:
    """The dialect called ``name`` (case-insensitive; ``fanuc`` is ``fanuc-mill``)."""
    key = name.strip().lower().replace("_", "-")
    key = {"fanuc": "fanuc-mill"}.get(key, key)
    found = DIALECTS.get(key)
    if found is None:
        raise InputError(f"unknown control {name!r} (expected {', '.join(DIALECTS)})")
    return found
