"""Property tests: program blocks and expressions; a run of any text ends or alarms."""

from __future__ import annotations

import contextlib

from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.errors import InputError
from opendnc.sim.haas.machine import MachineState
from opendnc.sim.haas.program import evaluate, parse_block, parse_expression
from opendnc.sim.haas.runner import BlockSource, ProgramRunner, RunnerEvent, StepResult

code_chars = st.text(alphabet="#[]+-*/=0123456789. GMXYZTPAHWNIFEQLTOD", max_size=40)
tokens = st.sampled_from(
    [
        "#1",
        "#100",
        "#[#1+1]",
        "2",
        ".5",
        "-",
        "+",
        "*",
        "/",
        "[",
        "]",
        "SIN",
        "ATAN",
        "ABS",
        "MOD",
        "GT",
        "EQ",
        "AND",
        "1.5",
        "#0",
    ]
)


@settings(deadline=None)  # wall-clock deadlines flake on a shared, loaded machine
@given(st.one_of(code_chars, st.lists(tokens, max_size=12).map(" ".join)))
def test_expression_only_input_errors(text: str) -> None:
    try:
        expr = parse_expression(text)
        evaluate(expr, {1: 2.0, 100: -3.0, 3: 0.0}.get)
    except InputError:
        pass


@settings(deadline=None)  # wall-clock deadlines flake on a shared, loaded machine
@given(st.one_of(code_chars, st.text(max_size=40)))
def test_block_parser_only_input_errors(line: str) -> None:
    with contextlib.suppress(InputError):
        parse_block(line)


block_lines = st.one_of(
    code_chars,
    st.sampled_from(
        [
            "#1 = #1 + 1",
            "IF [#1 GT 3] GOTO 20",
            "N20 DPRNT[V#1[22]]",
            "GOTO 20",
            "WHILE [#1 LT 5] DO1",
            "END1",
            "T1 M06",
            "M30",
            "M99",
            "G00 G91 X1",
            "POPEN",
        ]
    ),
)


@settings(deadline=None)  # wall-clock deadlines flake on a shared, loaded machine
@given(st.lists(block_lines, max_size=12))
def test_any_program_ends_waits_or_alarms(lines: list[str]) -> None:
    events: list[RunnerEvent] = []
    runner = ProgramRunner(
        BlockSource(lines), MachineState(), clock=lambda: 0.0, emit=events.append
    )
    result = runner.run(max_blocks=500)
    assert result in (StepResult.ENDED, StepResult.ALARM, StepResult.RAN)


@settings(deadline=None)  # wall-clock deadlines flake on a shared, loaded machine
@given(st.text(max_size=80))
def test_program_header_and_lines_only_input_errors(text: str) -> None:
    from opendnc.sim.haas.program import parse_header, program_lines

    try:
        header = parse_header(text)
    except InputError:
        header = None
    body = program_lines(text)
    assert all(line and line != "%" for line in body)
    if header is not None:
        assert 0 <= header.number <= 99999
