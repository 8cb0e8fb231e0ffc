"""The macro variable table (issue 15 item 3): the control model refuses what a Haas refuses.

Each case of the issue goes through the virtual control's MDC answer (``?E`` written as a
client would send it) and, for #3000, through a running program.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from opendnc.errors import InputError
from opendnc.haas import macros, mdc
from opendnc.sim.haas.control import HaasConfig, HaasControl
from opendnc.sim.haas.machine import Alarm, MachineState
from opendnc.sim.haas.runner import StepResult
from opendnc.sim.haas.store import ProgramStore


def make(tmp_path: Path) -> HaasControl:
    return HaasControl(HaasConfig(), ProgramStore(tmp_path), clock=lambda: 0.0)


def ask(control: HaasControl, line: str) -> str:
    return control.handle_mdc(mdc.parse_request(line)).to_payload()


def test_table_is_sorted_and_spans_do_not_overlap() -> None:
    for span in macros.TABLE:
        assert span.first <= span.last, span
    for before, after in zip(macros.TABLE, macros.TABLE[1:], strict=False):
        assert before.last < after.first, (before, after)


@pytest.mark.parametrize(
    ("line", "parts"),
    [
        ("?E3901 -1", "0"),
        ("?E3901 99999999999999999999", "0"),
        ("?E3901 2.5", "0"),
    ],
)
def test_counter_refuses_negative_huge_and_fractional_values(
    tmp_path: Path, line: str, parts: str
) -> None:
    control = make(tmp_path)
    assert ask(control, line) == "?"
    assert ask(control, "?Q500") == f"PROGRAM, MDI, IDLE, PARTS, {parts}"


def test_counter_accepts_whole_numbers_in_range(tmp_path: Path) -> None:
    control = make(tmp_path)
    assert ask(control, "?E3901 380") == "!"
    assert ask(control, "?Q500") == "PROGRAM, MDI, IDLE, PARTS, 380"
    assert ask(control, "?E3902 7") == "!"
    assert ask(control, "?Q403") == "M30 #2, 7"
    assert ask(control, "?E3902 -7.5") == "?"  # was stored as -7
    assert ask(control, "?Q403") == "M30 #2, 7"
    assert ask(control, f"?E3902 {macros.COUNTER_MAX}") == "!"
    assert ask(control, f"?E3902 {macros.COUNTER_MAX + 1}") == "?"


@pytest.mark.parametrize(
    "var", [1000, 1031, 1063, 3020, 3026, 4001, 4021, 4101, 4120, 5081, 5083, 5086]
)
def test_read_only_system_variables_refuse_writes(tmp_path: Path, var: int) -> None:
    control = make(tmp_path)
    before = ask(control, f"?Q600 {var}")
    assert ask(control, f"?E{var} 1") == "?"
    assert ask(control, f"?Q600 {var}") == before


def test_tool_in_spindle_reads_the_tool(tmp_path: Path) -> None:
    control = make(tmp_path)
    control.save_program("%\nO00002\nT7 M06\nM30\n%\n")
    control.start_program(2)
    while control.step() is StepResult.RAN:
        pass
    assert ask(control, "?Q600 3026") == "MACRO, 7.0"


def test_writable_neighbours_still_accept(tmp_path: Path) -> None:
    control = make(tmp_path)
    for var, value in ((10100, "1.5"), (5223, "-0.25"), (2001, "4.125"), (1, "3.0")):
        assert ask(control, f"?E{var} {value}") == "!", var
        assert ask(control, f"?Q600 {var}") == f"MACRO, {value}"


def test_numbers_the_control_does_not_have_are_refused(tmp_path: Path) -> None:
    control = make(tmp_path)
    for var in (4500, 5227, 19999, 99999):
        assert ask(control, f"?E{var} 1") == "?", var


def test_3000_over_mdc_stores_nothing(tmp_path: Path) -> None:
    control = make(tmp_path)
    assert ask(control, "?E3000 15") == "?"
    assert ask(control, "?Q600 3000") == "MACRO, 0.0"


def test_3000_in_a_program_raises_the_programmed_alarm(tmp_path: Path) -> None:
    control = make(tmp_path)
    control.save_program("%\nO00003\n#100 = 1\n#3000 = 15 (SPINDLE NOT READY)\n#100 = 2\nM30\n%\n")
    control.start_program(3)
    while (result := control.step()) is StepResult.RAN:
        pass
    assert result is StepResult.ALARM
    assert control.machine.alarms == [Alarm(1015, "SPINDLE NOT READY")]
    assert ask(control, "?Q500").startswith("PROGRAM, O00003, ALARM ON")
    assert ask(control, "?Q600 100") == "MACRO, 1.0"  # the run stopped at the alarm
    assert ask(control, "?Q600 3000") == "MACRO, 0.0"  # and nothing was stored


@pytest.mark.parametrize("value", ["0", "1000", "2.5", "-3"])
def test_3000_with_a_bad_alarm_number_is_a_program_error(tmp_path: Path, value: str) -> None:
    control = make(tmp_path)
    control.save_program(f"%\nO00004\n#3000 = {value} (X)\nM30\n%\n")
    control.start_program(4)
    while control.step() is StepResult.RAN:
        pass
    assert [alarm.code for alarm in control.machine.alarms] == [1001]  # PROGRAM ERROR


@pytest.mark.parametrize(
    ("var", "value", "reason"),
    [
        (3901, -1.0, "holds 0 to 2147483647, not -1"),
        (3901, 1e20, "holds 0 to 2147483647, not 1e+20"),
        (3902, -7.5, "whole numbers only"),
        (1000, 1.0, "read-only (discrete inputs)"),
        (3020, 0.0, "read-only (power-on timer)"),
        (3026, 3.0, "read-only (tool in the spindle)"),
        (4120, 1.0, "read-only (modal information"),
        (5081, 0.0, "read-only (tool length offset in effect)"),
        (3000, 15.0, "programmable alarm"),
        (4500, 1.0, "not a macro variable"),
    ],
)
def test_check_write_gives_the_reason(var: int, value: float, reason: str) -> None:
    with pytest.raises(InputError, match=re.escape(reason)):
        macros.check_write(var, value)
    with pytest.raises(InputError):
        MachineState().set(var, value)
