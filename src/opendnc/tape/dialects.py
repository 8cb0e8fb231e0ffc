"""The restart preamble per control dialect, generalised from the Haas one.

:func:`opendnc.haas.modal.restart_preamble` knows the modal state of a Fanuc-style program
(units, plane, offsets, tool, spindle, coolant, feed) and writes the blocks that restore it.
Controls differ in three places, which a :class:`Dialect` holds as data: how a comment is
written, the safety block, and how Z is retracted before anything moves. A dialect whose
retract is not known leaves it out and says so in the plan's warnings (docs/tape.md#restart).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

from opendnc.errors import InputError
from opendnc.haas.modal import ModalState, RestartPlan, restart_preamble


@dataclass(frozen=True, slots=True)
class Dialect:
    """How one control family writes the restart blocks."""

    name: str
    comment: str = "({})"  # a comment holding {}
    safety: str = "G00 {plane} G40 G80 G90"
    retract: tuple[str, ...] = ("G91 G28 Z0.", "G90")


DIALECTS: Mapping[str, Dialect] = MappingProxyType(
    {
        d.name: d
        for d in (
            Dialect("fanuc"),
            Dialect("haas"),
            # Siemens: ";" comments, no G80 (cycles are modal calls), Z to machine zero
            Dialect(
                "siemens", comment="; {}", safety="G0 {plane} G40 G90", retract=("SUPA G0 Z0",)
            ),
            Dialect("okuma", retract=()),
            Dialect("fagor", retract=()),
        )
    }
)


def get_dialect(name: str) -> Dialect:
    """The dialect called ``name``."""
    try:
        return DIALECTS[name]
    except KeyError:
        raise InputError(f"unknown dialect {name!r}: use one of {', '.join(DIALECTS)}") from None


def dialect_preamble(
    state: ModalState, line: int, dialect: Dialect, *, retract: bool = True
) -> RestartPlan:
    """The blocks (without the ``%`` framing) that restore ``state`` before ``line``."""
    plan = restart_preamble(state, line, retract=retract)
    plane = state.plane or "G17"
    haas_safety = f"G00 {plane} G40 G80 G90"
    haas_comment = f"(OPENDNC RESTART AT LINE {line})"
    out: list[str] = []
    warnings = list(plan.warnings)
    blocks = list(plan.preamble[1:])  # the "%" is the feed's framing
    index = 0
    while index < len(blocks):
        block = blocks[index]
        if block == haas_comment:
            out.append(dialect.comment.format(f"OPENDNC RESTART AT LINE {line}"))
        elif block == haas_safety:
            out.append(dialect.safety.format(plane=plane))
        elif retract and block == "G91 G28 Z0." and blocks[index + 1 : index + 2] == ["G90"]:
            index += 1
            if dialect.retract:
                out.extend(dialect.retract)
            else:
                warnings.append(
                    f"no Z retract is known for {dialect.name}: retract by hand before the restart"
                )
        else:
            out.append(block)
        index += 1
    return RestartPlan(line, tuple(out), tuple(warnings))
