"""Round trip: the virtual Haas runs a program, the dry run checks it, and both agree on
where the machine ends, which tool is in the spindle and what the macro variables hold."""

from __future__ import annotations

import math
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.gcode.program import program_lines
from opendnc.nccheck import Budget, CheckResult, MachineLimits, check_text
from opendnc.sim.haas.control import HaasConfig, HaasControl
from opendnc.sim.haas.machine import MachineState
from opendnc.sim.haas.runner import BlockSource, ProgramRunner, RunnerEvent, StepResult
from opendnc.sim.haas.store import ProgramStore

PROGRAM = """%
O01234 (ROUND TRIP)
#5221 = -12.5
#5222 = -7.25
#5223 = -9.
#5241 = -3.
#5242 = -4.
#5243 = -5.
G20 G17 G40 G80 G90
G28 G91 Z0.
G28 X0. Y0.
G90
T4 M06
G00 G54 X1. Y2.
Z0.5
#100 = 0
#101 = 0
WHILE [#100 LT 5] DO1
#101 = #101 + #100 * 2
G91 X0.25
G90
#100 = #100 + 1
END1
IF [#101 GT 10] GOTO 50
#102 = 99
N50 #103 = #5041 + #5042
G55 X1.5 Y-1.
G53 Z-2.
#104 = #5023
T7 M06
#105 = #3026
#106 = SQRT[#101] * SIN[30.] + ATAN[1.]/[1.]
M30
%
"""


def run_virtual(text: str) -> tuple[MachineState, StepResult]:
    machine = MachineState()
    events: list[RunnerEvent] = []
    runner = ProgramRunner(
        BlockSource(program_lines(text)), machine, clock=lambda: 0.0, emit=events.append
    )
    return machine, runner.run(max_blocks=100_000)


def agree(machine: MachineState, result: CheckResult, variables: list[int]) -> None:
    end = result.end
    for axis, letter in enumerate("XYZ"):
        assert math.isclose(end.machine_position[letter], machine.machine_position[axis])
        assert math.isclose(end.position[letter], machine.work_position(axis))
    assert end.tool == str(machine.tool)
    for number in variables:
        assert math.isclose(end.variables[number], machine.get(number) or 0.0), number


def test_the_virtual_haas_and_the_dry_run_agree(tmp_path: Path) -> None:
    # the whole virtual control: the program stored in its memory and started (MEM mode)
    control = HaasControl(HaasConfig(), ProgramStore(tmp_path), clock=lambda: 0.0)
    number = control.save_program(PROGRAM)
    control.start_program(number)
    for _ in range(10_000):
        if control.step() is not StepResult.RAN:
            break
    assert not control.machine.alarms
    assert control.machine.m30_counter_1 == 1
    machine = control.machine
    result = check_text(PROGRAM, name="O01234")
    assert result.problems == ()
    assert result.end.ended
    agree(machine, result, [100, 101, 103, 104, 105, 106, 3901])
    assert 102 not in result.end.variables
    assert machine.get(102) is None
    # the values the program computed, worked out by hand
    assert result.end.variables[101] == 20.0  # 2 * (0 + 1 + 2 + 3 + 4)
    assert result.end.variables[104] == -2.0  # G53 Z-2.
    assert result.end.variables[105] == 7.0
    assert result.end.machine_position == {"X": -1.5, "Y": -5.0, "Z": -2.0}


# Generated programs: offsets, absolute and incremental moves, G53, G28, tools, arithmetic.
_block = st.one_of(
    st.builds(
        lambda axis, value: f"#{5221 + axis} = {value:.3f}",
        st.integers(0, 2),
        st.floats(-20, 20, allow_nan=False),
    ),
    st.builds(
        lambda g, x, y, z: f"{g} X{x:.3f} Y{y:.3f} Z{z:.3f}",
        st.sampled_from(["G90 G00", "G91 G00", "G90 G01 F10.", "G91 G01 F10."]),
        st.floats(-5, 5, allow_nan=False),
        st.floats(-5, 5, allow_nan=False),
        st.floats(-5, 5, allow_nan=False),
    ),
    st.builds(lambda z: f"G53 Z{z:.3f}", st.floats(-10, 0, allow_nan=False)),
    st.sampled_from(["G28 G91 Z0.", "G90 G28 X0. Y0.", "G54", "G55", "G90", "G91"]),
    # a tool change stops the spindle (Haas, Fanuc): the program starts it again
    st.builds(lambda t: f"T{t} M06\nM03", st.integers(1, 20)),
    st.builds(lambda n, v: f"#{n} = #{n} + {v}", st.integers(100, 105), st.integers(-9, 9)),
    st.builds(lambda n: f"#{n} = #5041 + #5043", st.integers(100, 105)),
    st.builds(
        lambda count, dx: (
            f"#110 = 0\nWHILE [#110 LT {count}] DO1\nG91 G01 X{dx:.3f} F10.\n"
            "#110 = #110 + 1\nEND1\nG90"
        ),
        st.integers(0, 4),
        st.floats(-2, 2, allow_nan=False),
    ),
    st.builds(lambda n: f"IF [#100 GT {n}] GOTO 900", st.integers(-20, 20)),
)


@settings(max_examples=80, deadline=None)
@given(st.lists(_block, max_size=25))
def test_generated_programs_agree(blocks: list[str]) -> None:
    start = ["G28 G91 Z0.", "G28 X0. Y0.", "G90 T1 M06", "S1000 M03"]
    text = "%\nO01000\n" + "\n".join([*start, *blocks, "N900 G90", "M30"]) + "\n%\n"
    machine, step = run_virtual(text)
    assert step is StepResult.ENDED
    # the virtual Haas starts with every work offset at 0: the dry run is told so, as the
    # server tells it the offsets a machine's configuration gives
    zero = {"X": 0.0, "Y": 0.0, "Z": 0.0}
    machine_limits = MachineLimits(work_offsets={"G54": zero, "G55": zero})
    result = check_text(text, machine=machine_limits, budget=Budget(seconds=5.0))
    assert result.errors == ()
    agree(machine, result, [n for n in (*range(100, 106), 110) if machine.get(n) is not None])
