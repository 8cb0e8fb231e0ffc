"""Program parsing, macro expressions and the runner (with an injected clock)."""

from __future__ import annotations

import math

import pytest

from opendnc.errors import InputError
from opendnc.sim.haas.machine import MachineState, Mode, Status
from opendnc.sim.haas.program import (
    Assign,
    Dprnt,
    IfGoto,
    PortControl,
    While,
    Words,
    evaluate,
    parse_block,
    parse_expression,
    parse_header,
    program_lines,
)
from opendnc.sim.haas.runner import (
    AlarmRaised,
    BlockSource,
    CycleEnded,
    DprntLine,
    PortCode,
    ProgramRunner,
    RunnerEvent,
    StepResult,
    ToolChanged,
)


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def run(
    text: str,
    machine: MachineState | None = None,
    surface: object = None,
    clock: FakeClock | None = None,
) -> tuple[list[RunnerEvent], MachineState, ProgramRunner]:
    machine = machine or MachineState()
    events: list[RunnerEvent] = []
    runner = ProgramRunner(
        BlockSource(program_lines(text)),
        machine,
        clock=clock or FakeClock(),
        emit=events.append,
        surface=surface,  # type: ignore[arg-type]
    )
    runner.run()
    return events, machine, runner


def lines(events: list[RunnerEvent]) -> list[str]:
    return [e.text for e in events if isinstance(e, DprntLine)]


@pytest.mark.parametrize(
    ("expr", "value"),
    [
        ("1 + 2 * 3", 7.0),
        ("[1 + 2] * 3", 9.0),
        ("-2 * -3", 6.0),
        ("10 / 4", 2.5),
        ("7 MOD 3", 1.0),
        ("SIN[30]", 0.5),
        ("COS[60]", 0.5),
        ("ATAN[1]/[1]", 45.0),
        ("ATAN[-1]/[-1]", 225.0),
        ("SQRT[16] + ABS[-2]", 6.0),
        ("ROUND[2.5] + FIX[2.7] + FUP[2.1]", 8.0),
        ("ROUND[-2.5]", -3.0),
        ("3 GT 2", 1.0),
        ("[3 LT 2] OR [1 EQ 1]", 1.0),
        ("[1 GE 1] AND [2 LE 1]", 0.0),
        ("#1 + 1", 3.0),
        ("#[#1 + 1]", 20.0),
        ("#0 EQ #7", 1.0),
        ("#7 + 1", 1.0),
    ],
)
def test_expressions(expr: str, value: float) -> None:
    variables = {1: 2.0, 3: 20.0}
    result = evaluate(parse_expression(expr), variables.get)
    assert result is not None
    assert math.isclose(result, value, abs_tol=1e-9)


@pytest.mark.parametrize("expr", ["1 +", "[1", "SIN 30", "1 2", "#", "@"])
def test_bad_expressions(expr: str) -> None:
    with pytest.raises(InputError):
        parse_expression(expr)


def test_division_by_zero() -> None:
    with pytest.raises(InputError, match="division by zero"):
        evaluate(parse_expression("1/0"), lambda n: None)


def test_block_kinds() -> None:
    assert isinstance(parse_block("#100 = #1 * 2").statement, Assign)
    assert isinstance(parse_block("IF [#1 GT 5] GOTO20").statement, IfGoto)
    assert isinstance(parse_block("WHILE [#1 LT 3] DO1").statement, While)
    assert isinstance(parse_block("DPRNT[X#1[44]]").statement, Dprnt)
    assert parse_block("POPEN").statement == PortControl(True)
    block = parse_block("N20 G00G91X.5 (move) ;")
    assert block.number == 20
    assert isinstance(block.statement, Words)
    assert [letter for letter, _ in block.statement.words] == ["G", "G", "X"]
    assert parse_block("/M00").deleted


def test_header() -> None:
    assert parse_header("\n%\nO05555(CS390_Test_NC)\nG0\n").name == "O05555"
    assert parse_header("%\nO05555(CS390_Test_NC)\n").title == "CS390_Test_NC"
    with pytest.raises(InputError):
        parse_header("%\nG00 X1\n%")


def test_program_lines_strip_tape_framing() -> None:
    text = "\n%\nO00001 (T)\nG00 X1\n\nM30\n\n%\n\x1a\x1a"
    assert program_lines(text) == ["G00 X1", "M30"]


def test_surface_probe_program() -> None:
    text = """%
O00010
G00 G90 G54 X0 Y0
#100 = 0
WHILE [#100 LT 3] DO1
G65 P9995 W54. A20. H-1.
DPRNT[X#5041[24]*Y#5042[24]*Z#5223[24]]
G00 G91 X.5
#100 = #100 + 1
END1
M30
%"""
    events, machine, runner = run(text, surface=lambda x, y: -1.0 - 0.1 * x)
    assert lines(events) == [
        "X 0.0000 Y 0.0000 Z-1.0000",
        "X 0.5000 Y 0.0000 Z-1.0500",
        "X 1.0000 Y 0.0000 Z-1.1000",
    ]
    assert machine.get(5223) == pytest.approx(-1.1)
    # skip position: work Z of the last touch, measured against the previous G54 Z
    assert machine.get(5063) == pytest.approx(-0.05)
    assert runner.finished


def test_m30_counters_cycle_times_and_tools() -> None:
    clock = FakeClock()
    machine = MachineState()
    text = "%\nO00011\nT3 M06\nT5\nM06\nM30\n%"
    events, _, runner = run(text, machine, clock=clock)
    assert [e for e in events if isinstance(e, ToolChanged)] == [
        ToolChanged(3, 1),
        ToolChanged(5, 2),
    ]
    assert machine.tool == 5
    assert machine.tool_changes == 2
    assert machine.m30_counter_1 == 1
    assert machine.get(3901) == 1.0
    times = runner.times
    second = ProgramRunner(
        BlockSource(program_lines(text)), machine, clock=clock, emit=events.append, times=times
    )
    clock.now += 42.0
    assert second.run() is StepResult.ENDED
    assert times.last == 42.0
    assert times.previous == 0.0
    assert events[-1] == CycleEnded(42.0, 2)
    assert machine.status is Status.IDLE
    assert machine.mode is Mode.MEM


def test_goto_if_then_and_popen() -> None:
    text = """%
O00012
POPEN
#1 = 1
N10 #1 = #1 * 2
IF [#1 LT 10] GOTO10
IF [#1 EQ 16] THEN #2 = 7
DPRNT[A#1[20]*B#2[10]]
PCLOS
M30
%"""
    events, _, _ = run(text)
    assert lines(events) == ["A16 B7"]
    assert [e.code for e in events if isinstance(e, PortCode)] == [b"\x12", b"\x14"]


@pytest.mark.parametrize(
    ("text", "detail"),
    [
        ("GOTO 99\nM30", "no block N99"),
        ("#1 = [1 +\nM30", "unexpected end"),
        ("G65 P9995 W54. A20. H-1.\nM30", "no surface"),
        ("G65 P9995 A0. T1\nM30", "A20"),
        ("M98 P100\nM30", "subprograms"),
        ("#5021 = 1\nM30", "read-only"),
        ("WHILE [1 EQ 2] DO1\nM30", "without END1"),
        ("DPRNT[#1[09]]\nM30", "illegal DPRNT format"),
    ],
)
def test_program_faults_raise_alarms(text: str, detail: str) -> None:
    events, machine, _ = run(text)
    alarm = events[-1]
    assert isinstance(alarm, AlarmRaised)
    assert detail in alarm.detail
    assert machine.status is Status.ALARM


def test_strict_probe_needs_probe_on_and_reach() -> None:
    machine = MachineState()
    events: list[RunnerEvent] = []
    source = BlockSource(["G65 P9832", "G00 Z0.5", "G65 P9995 W54. A20. H-1.", "M30"])
    runner = ProgramRunner(
        source,
        machine,
        clock=FakeClock(),
        emit=events.append,
        surface=lambda x, y: 0.0,
        strict_probe=True,
    )
    assert runner.run() is StepResult.ENDED
    far = ProgramRunner(
        BlockSource(["G65 P9832", "G00 Z5", "G65 P9995 W54. A20. H-1.", "M30"]),
        machine,
        clock=FakeClock(),
        emit=events.append,
        surface=lambda x, y: 0.0,
        strict_probe=True,
    )
    assert far.run() is StepResult.ALARM


def test_streamed_source_waits_for_more_blocks() -> None:
    machine = MachineState()
    events: list[RunnerEvent] = []
    source = BlockSource(complete=False)
    runner = ProgramRunner(source, machine, clock=FakeClock(), emit=events.append, mode=Mode.DNC)
    assert runner.step() is StepResult.WAITING
    source.append("#1 = 4")
    source.append("DPRNT[V#1[10]]")
    assert runner.run() is StepResult.WAITING
    assert lines(events) == ["V4"]
    source.append("M30")
    source.close()
    assert runner.run() is StepResult.ENDED
    assert machine.m30_counter_1 == 1


def test_machine_variables() -> None:
    machine = MachineState()
    machine.set(5221, 1.0)  # G54 X
    machine.machine_position[0] = 3.0
    assert machine.get(5041) == 2.0
    assert machine.get(5021) == 3.0
    machine.settings[261] = 2
    assert machine.get(20261) == 2.0
    machine.set(100, None)
    assert machine.get(100) is None
    assert machine.get(0) is None
    with pytest.raises(InputError):
        machine.set(5041, 1.0)
    with pytest.raises(InputError):
        machine.set(100, math.inf)


def test_tape_delimiters_in_a_stream_are_empty_blocks() -> None:
    events, machine, _ = run("")  # warm-up: empty program ends at once
    source = BlockSource(["%", "O00100", "DPRNT[OK]", "M30", "%"])
    runner = ProgramRunner(source, machine, clock=FakeClock(), emit=events.append)
    assert runner.run() is StepResult.ENDED
    assert lines(events) == ["OK"]
