"""Property tests: the simulator's own parsers of wire and file data never fail untyped."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from opendnc.errors import ControlRefused
from opendnc.lsv2.constants import ErrorCode
from opendnc.lsv2.payloads import ScopeSignal
from opendnc.sim.tnc import oplog, scope
from opendnc.sim.tnc.machine import parse_program
from opendnc.sim.tnc.plc import PlcMemory, resolve_data_path, table_rows
from opendnc.sim.tnc.profiles import PROFILES

_PLC = PlcMemory(PROFILES["itnc530"].plc)
_TABLE_LINES = st.lists(
    st.one_of(
        st.just("BEGIN TOOL.T MM"),
        st.just("T     NAME    L"),
        st.just("[END]"),
        st.text(alphabet=st.characters(codec="latin-1"), max_size=40),
    ),
    max_size=8,
)


@given(_TABLE_LINES)
def test_table_parser_total(lines: list[str]) -> None:
    rows = table_rows("\n".join(lines))
    assert all(isinstance(r, dict) for r in rows)


@given(st.text(alphabet=st.characters(codec="latin-1"), max_size=300))
def test_program_parser_total(text: str) -> None:
    blocks = parse_program(text)
    assert len(blocks) == len(text.splitlines())


@given(st.text(max_size=60))
def test_oplog_request_parser_only_refuses(text: str) -> None:
    try:
        request = oplog.parse_request(text)
    except ControlRefused as exc:
        code = exc.code
    else:
        assert request.name
        return
    assert code == ErrorCode.T_ER_BAD_PARAMETER


@given(
    st.lists(
        st.builds(
            ScopeSignal,
            st.integers(0, 0xFFFF),
            st.integers(0, 0xFFFF),
            st.integers(0, 0xFFFFFFFF),
        ),
        max_size=20,
    )
)
def test_scope_selection_only_refuses(selectors: list[ScopeSignal]) -> None:
    try:
        signals = scope.parse_selection(tuple(selectors))
    except ControlRefused as exc:
        code = exc.code
    else:
        assert len(signals) == len(selectors)
        return
    assert code in (scope.OSZI_CHSEL, scope.TOO_MANY_SIGNALS)


@given(
    st.one_of(
        st.text(max_size=60),
        st.builds(
            lambda a, n: f"\\PLC\\memory\\{a}\\{n}",
            st.sampled_from("MIOTCBWDSKXQ"),
            st.integers(-5, 10**7),
        ),
        st.builds(lambda n: f"/PLC/program/symbol/global/{n}", st.text(max_size=20)),
        st.builds(
            lambda n, c: f"\\TABLE\\TOOL\\T\\{n}\\{c}", st.integers(0, 99), st.text(max_size=6)
        ),
    )
)
def test_data_paths_resolve_or_refuse(path: str) -> None:
    rows = {1: {"T": "1", "L": "+5", "DOC": "x"}}
    try:
        value = resolve_data_path(path, _PLC, rows)
    except ControlRefused as exc:
        code = exc.code
    else:
        assert value.to_payload()[:4] == int(value.value_type).to_bytes(4, "big")
        return
    assert code in (52, 63)


@pytest.mark.parametrize("key", list(PROFILES))
def test_plc_reads_inside_the_image_always_work(key: str) -> None:
    plc = PlcMemory(PROFILES[key].plc)
    assert len(plc.read(len(plc.image) - 255, 255)) == 255
    with pytest.raises(ControlRefused):
        plc.read(len(plc.image), 1)
