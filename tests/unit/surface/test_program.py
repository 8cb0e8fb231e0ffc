"""The probing program: input checks, serpentine order, and what it does in the runner."""

from __future__ import annotations

import pytest

from opendnc.errors import InputError
from opendnc.sim.haas.machine import MachineState
from opendnc.sim.haas.program import parse_header, program_lines
from opendnc.sim.haas.runner import AlarmRaised, BlockSource, DprntLine, ProgramRunner, RunnerEvent
from opendnc.surface.grid import Grid, Units, parse_grid, parse_origin
from opendnc.surface.program import (
    ProbeMoves,
    check_moves,
    generate,
    grid_from_program,
    parse_program_number,
)


def run_program(
    text: str, surface: object, machine: MachineState | None = None
) -> tuple[list[RunnerEvent], MachineState]:
    machine = machine or MachineState()
    events: list[RunnerEvent] = []
    runner = ProgramRunner(
        BlockSource(program_lines(text)),
        machine,
        clock=lambda: 0.0,
        emit=events.append,
        surface=surface,  # type: ignore[arg-type]
        strict_probe=True,
    )
    runner.run()
    return events, machine


@pytest.mark.parametrize("number", ["O08000", "8123", "O8999", "O09000", "9995", "O9999"])
def test_8000_and_9000_series_refused(number: str) -> None:
    with pytest.raises(InputError, match="series holds the control's own probing routines"):
        parse_program_number(number)
    with pytest.raises(InputError, match="series"):
        generate(Grid(2, 2, 1, 1), number=int(number.lstrip("O")))


@pytest.mark.parametrize(
    ("text", "number"), [("O01234", 1234), ("7999", 7999), ("o10000", 10000), ("O99999", 99999)]
)
def test_program_numbers_accepted(text: str, number: int) -> None:
    assert parse_program_number(text) == number


@pytest.mark.parametrize("text", ["O0", "O100000", "P1234", "", "O12a"])
def test_bad_program_numbers(text: str) -> None:
    with pytest.raises(InputError):
        parse_program_number(text)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"columns": 1, "rows": 5}, "too small"),
        ({"columns": 400, "rows": 400}, "at most"),
        ({"pitch_x": 0.0}, "pitch must be a positive"),
        ({"pitch_y": -1.0}, "pitch-y must be a positive"),
        ({"pitch_x": 0.00001}, "below the printed resolution"),
        ({"pitch_x": float("nan")}, "positive"),
    ],
)
def test_grid_checks(kwargs: dict[str, float], message: str) -> None:
    args: dict[str, object] = {"columns": 3, "rows": 3, "pitch_x": 0.5, "pitch_y": 0.5}
    args.update(kwargs)
    with pytest.raises(InputError, match=message):
        Grid(**args)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("moves", "message"),
    [
        (ProbeMoves(0.1, 0.1, 0.1, 30), "clearance Z0.1 must be above approach"),
        (ProbeMoves(0.05, 0.1, 0.1, 30), "must be above approach"),
        (ProbeMoves(1, -0.1, 0.1, 30), "approach"),
        (ProbeMoves(1, 0.1, 0, 30), "depth"),
        (ProbeMoves(1, 0.1, 0.1, 0), "feed"),
    ],
)
def test_move_checks(moves: ProbeMoves, message: str) -> None:
    with pytest.raises(InputError, match=message):
        check_moves(moves)


def test_parse_grid_and_origin() -> None:
    assert parse_grid("10x8") == (10, 8)
    assert parse_grid(" 3 X 4 ") == (3, 4)
    assert parse_origin("1.5,-2") == (1.5, -2.0)
    for bad in ("10", "x10", "10x", "-1x2", "1.5x2"):
        with pytest.raises(InputError, match="bad grid"):
            parse_grid(bad)
    for bad in ("1", "a,b", "1,2,3", "inf,0"):
        with pytest.raises(InputError, match="origin"):
            parse_origin(bad)


def test_serpentine_order() -> None:
    grid = Grid(3, 3, 1.0, 2.0, 10.0, 20.0)
    assert [(p.row, p.col) for p in grid.points] == [
        (1, 1), (1, 2), (1, 3), (2, 3), (2, 2), (2, 1), (3, 1), (3, 2), (3, 3),
    ]  # fmt: skip
    assert grid.points[3].x == 12.0
    assert grid.points[3].y == 22.0
    assert [p.number for p in grid.points] == list(range(1, 10))


def test_program_layout_and_header() -> None:
    made = generate(Grid(4, 3, 0.5, 0.25, 1.0, -1.0), number=4321, tool=20)
    text = made.text
    assert text.startswith("%\nO04321 (OPENDNC SURFACE MAP 4 X 3)\n")
    assert text.endswith("M30\n%\n")
    assert parse_header(text).number == 4321
    for needed in ("G20", "G54", "G65 P9832", "G65 P9833", "T20 M06", "G43 H20", "G103 P1"):
        assert needed in text
    assert text.count("G65 P9995 W54. A20. H-0.2000") == 12
    assert text.count("DPRNT[P#141[20]*X#5041[44]*Y#5042[44]*Z#142[44]]") == 12
    assert grid_from_program(text) == made.grid
    metric = generate(Grid(2, 2, 5, 5, units=Units.MM), moves=ProbeMoves(25, 2.5, 2.5, 750))
    assert "G21" in metric.text
    assert "Z#142[53]" in metric.text
    assert grid_from_program(metric.text) == metric.grid
    with pytest.raises(InputError, match="not an opendnc surface program"):
        grid_from_program("%\nO1\nM30\n%\n")


def test_program_restores_the_work_offset_and_prints_heights() -> None:
    machine = MachineState()
    machine.variables[5223] = -5.0  # operator's G54 Z
    made = generate(Grid(3, 2, 1.0, 1.0))
    events, machine = run_program(made.text, lambda x, y: -5.0 + 0.01 * x - 0.02 * y, machine)
    lines = [e.text for e in events if isinstance(e, DprntLine)]
    assert lines[0] == "SURFACE START ZOFFSET  -5.0000"
    assert lines[-1] == "SURFACE END"
    assert lines[1:-1] == [
        "P1 X   0.0000 Y   0.0000 Z   0.0000",
        "P2 X   1.0000 Y   0.0000 Z   0.0100",
        "P3 X   2.0000 Y   0.0000 Z   0.0200",
        "P4 X   2.0000 Y   1.0000 Z   0.0000",
        "P5 X   1.0000 Y   1.0000 Z  -0.0100",
        "P6 X   0.0000 Y   1.0000 Z  -0.0200",
    ]
    assert machine.variables[5223] == -5.0
    assert not machine.alarms


def test_surface_out_of_reach_alarms_instead_of_printing() -> None:
    made = generate(Grid(2, 2, 1.0, 1.0))
    events, _machine = run_program(made.text, lambda x, y: -1.0 if x > 0.5 else 0.0)
    lines = [e.text for e in events if isinstance(e, DprntLine)]
    assert lines == ["SURFACE START ZOFFSET   0.0000", "P1 X   0.0000 Y   0.0000 Z   0.0000"]
    alarms = [e for e in events if isinstance(e, AlarmRaised)]
    assert len(alarms) == 1
    assert "no surface" in alarms[0].detail
