"""A Haas's mode in the status: MTConnect's CONTROLLER_MODE, mapped where the connector reads
Q104, with the control's own word kept beside it (docs/server.md#machine-status)."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest

from opendnc.haas.mdc import parse_reply
from opendnc.server.core.events import MachineStatusChanged
from opendnc.server.core.status import MachineStatus
from opendnc.server.kinds.haas_ngc.connector import mdc_status
from opendnc.server.outputs.items import items_of

Q500 = parse_reply("PROGRAM, O00123, IDLE, PARTS, 380")

# Q104 replies as NGC and classic controls send them (docs/haas.md#q-commands), and the
# CONTROLLER_MODE values MTConnect Part 2 defines for each kind of mode.
CASES = [
    ("MODE, MEM", "AUTOMATIC", "MEM"),
    ("MODE, (MEM)", "AUTOMATIC", "MEM"),
    ("MODE, DNC", "AUTOMATIC", "DNC"),
    ("MODE, MDI", "MANUAL_DATA_INPUT", "MDI"),
    ("MODE, (MDI)", "MANUAL_DATA_INPUT", "MDI"),
    ("MODE, JOG", "MANUAL", "JOG"),
    ("MODE, HANDLE JOG", "MANUAL", "HANDLE JOG"),
    ("MODE, ZERO", "MANUAL", "ZERO"),
    ("MODE, (ZERO RET)", "MANUAL", "ZERO RET"),
    ("MODE, EDIT", "EDIT", "EDIT"),
    ("MODE, LIST PROG", "EDIT", "LIST PROG"),
    ("MODE, (setng)", "", "SETNG"),  # a word not known: no mode, the word still shown
]


@pytest.mark.parametrize(("reply", "mode", "native"), CASES)
def test_the_status_carries_the_mtconnect_mode_and_the_controls_word(
    reply: str, mode: str, native: str
) -> None:
    status = mdc_status(Q500, parse_reply(reply), None)
    assert (status.mode, status.native_mode) == (mode, native)
    assert status.as_json()["native_mode"] == native


@pytest.mark.parametrize(("reply", "mode", "native"), CASES)
def test_the_outputs_take_the_mode_as_the_status_has_it(reply: str, mode: str, native: str) -> None:
    status = mdc_status(Q500, parse_reply(reply), None)
    items = items_of(MachineStatusChanged("vf2", True, status))
    assert items["controller_mode"] == (mode or None)


@pytest.mark.parametrize("word", ["MEM", "MDI", "(JOG)", "mem"])
def test_the_outputs_map_no_control_words_themselves(word: str) -> None:
    # One place maps a Haas's words: the connector. A status whose mode is not MTConnect's is
    # a mode not known to the outputs, not one they guess.
    status = MachineStatus(at=datetime.now(UTC), available=True, mode=word)
    items = items_of(MachineStatusChanged("vf2", True, status))
    assert items["controller_mode"] is None
