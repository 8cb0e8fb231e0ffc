"""Hypothesis: whatever a (broken or hostile) control answers, every operation ends with its
result or a typed DncError, and every data parser raises only its typed error."""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from datetime import datetime

from hypothesis import given, settings
from hypothesis import strategies as st

from opendnc.errors import DncError, InputError, RemoteProtocolError
from opendnc.lsv2 import ops
from opendnc.lsv2.constants import Family, MemoryType, RunInfo
from opendnc.lsv2.messages import (
    CommandDone,
    DataPathReply,
    DateTimeReply,
    DirInfoReply,
    DirReply,
    FileData,
    FileDone,
    FileInfoReply,
    MachineParameterReply,
    MemoryReply,
    Message,
    Ok,
    ParametersReply,
    Refused,
    RunInfoReply,
    ScopeChannelReply,
    ScopeDataReply,
    ScopeSignalReply,
    StatusReply,
    SystemInfoReply,
    VersionReply,
)
from opendnc.lsv2.ops.base import Expect, Op, Receive, Send, SessionState, Slow
from opendnc.lsv2.payloads import (
    DirectoryInfo,
    FileEntry,
    ScopeChannel,
    ScopeSamples,
    ScopeSignal,
    ScopeSignalInfo,
)
from opendnc.lsv2.plc import parse_operand
from opendnc.lsv2.runinfo import decode_run_info
from opendnc.lsv2.tables import parse_table
from tests.unit.lsv2.samples import PARAMS, SAMPLES

Factory = Callable[[SessionState], Op[object]]

OPERATIONS: list[Factory] = [
    lambda s: ops.connect(s),
    lambda s: ops.list_dir(s, "TNC:/nc_prog"),
    lambda s: ops.walk(s, "TNC:/"),
    lambda s: ops.drives(s),
    lambda s: ops.file_info(s, "TNC:/a.h"),
    lambda s: ops.make_dir(s, "TNC:/a/b/c"),
    lambda s: ops.remove_dir(s, "TNC:/a", missing_ok=True),
    lambda s: ops.copy_file(s, "TNC:/a/x.h", "TNC:/b/"),
    lambda s: ops.upload(s, "TNC:/x.h", b"1 L X+1\n" * 100, binary=False),
    lambda s: ops.download(s, "TNC:/x.h", lambda b: None, binary=False, progress=lambda d, t: None),
    lambda s: ops.nc_errors(s),
    lambda s: ops.uptimes(s),
    lambda s: ops.execution_mode(s),
    lambda s: ops.program_state(s),
    lambda s: ops.axes_position(s),
    lambda s: ops.current_tool(s),
    lambda s: ops.read_plc(s, "W4", 200),
    lambda s: ops.read_plc_memory(s, MemoryType.STRING, 0, 2),
    lambda s: ops.read_data_path(s, "/PLC/memory/W/2"),
    lambda s: ops.write_machine_parameter(s, "7230.0", "1"),
    lambda s: ops.emulate_key(s, 0x01C0),
    lambda s: ops.date_time(s),
    lambda s: ops.screen_dump(s, stamp=datetime(2024, 1, 1)),
    lambda s: ops.operations_log(s, since=datetime(2024, 1, 1)),
    lambda s: ops.read_table(s, "TNC:/table/tool.t"),
    lambda s: ops.scope_channels(s),
    lambda s: ops.scope_record(s, [ScopeSignal(1, 0)], interval=600, blocks=2),
    lambda s: ops.system_info_all(s),
]

text = st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=255), max_size=12)
entries = st.builds(
    FileEntry, text, st.integers(0, 2**32 - 1), st.integers(0, 2**32 - 1), st.integers(0, 255)
)
refusal = st.builds(Refused, st.sampled_from([None, 24, 32, 34, 55, 57]))
listing = st.one_of(
    st.builds(DirReply, st.lists(entries, max_size=3).map(tuple)), st.just(FileDone())
)
data_block = st.one_of(st.builds(FileData, st.binary(max_size=40)), st.just(FileDone()))
scope_block = st.builds(
    ScopeDataReply,
    st.integers(0, 9),
    st.lists(
        st.builds(
            ScopeSamples,
            st.lists(st.integers(-(2**31), 2**31 - 1), min_size=32, max_size=32).map(tuple),
        ),
        max_size=2,
    ).map(tuple),
)

# What a control plausibly answers to each request: the right kind with random contents.
ANSWERS: dict[str, st.SearchStrategy[Message]] = {
    "R_VR": st.builds(VersionReply, st.lists(text, max_size=6).map(tuple)),
    "R_PR": st.just(ParametersReply(PARAMS)),
    "R_CI": st.builds(SystemInfoReply, st.integers(0, 3), st.integers(0, 2**32 - 1)),
    "R_RI": st.builds(RunInfoReply, st.binary(max_size=30)),
    "R_MB": st.builds(MemoryReply, st.binary(max_size=260)),
    "R_DR": listing,
    "R_FL": data_block,
    "R_FI": st.builds(FileInfoReply, entries),
    "R_DI": st.builds(DirInfoReply, st.builds(DirectoryInfo, st.integers(0, 2**32 - 1), text)),
    "R_DP": st.sampled_from([DataPathReply(3, 5), DataPathReply(8, "x"), DataPathReply(5, 1.5)]),
    "R_MC": st.builds(MachineParameterReply, text),
    "R_DT": st.builds(DateTimeReply, st.integers(0, 2**32 - 1)),
    "R_ST": st.builds(StatusReply, st.binary(min_size=12, max_size=12)),
    "R_OC": st.one_of(
        st.builds(
            ScopeChannelReply,
            st.builds(
                ScopeChannel,
                st.integers(0, 9),
                st.integers(0, 9999),
                st.integers(0, 10),
                text.map(lambda t: t[:12]),
            ),
        ),
        st.just(FileDone()),
    ),
    "R_OP": st.builds(
        ScopeSignalReply,
        st.lists(
            st.builds(
                ScopeSignalInfo,
                text.map(lambda t: t[:8]),
                st.floats(allow_nan=False, allow_infinity=False),
            ),
            max_size=2,
        ).map(tuple),
    ),
    "R_OD": scope_block,
    "T_OK": st.one_of(listing, data_block, scope_block, st.just(Ok())),
    "EXPECT": st.builds(CommandDone, st.sampled_from([27, 12]), st.just(100)),
}
anything = st.one_of(st.none(), st.sampled_from(SAMPLES), refusal, st.just(Ok()))


@settings(max_examples=600, deadline=None)
@given(st.sampled_from(OPERATIONS), st.sampled_from(list(Family)), st.data())
def test_any_answers_give_result_or_typed_error(
    factory: Factory, family: Family, data: st.DataObject
) -> None:
    state = SessionState(safe_mode=False, params=PARAMS, family=family)
    op = factory(state)
    try:
        step = next(op)
        for _ in range(60):
            if isinstance(step, Send):
                sent = step.message
                step = op.send(None)  # sent; the operation works, then asks for the answer
                assert isinstance(step, Receive), step
                step = sent  # the answer drawn below is the one to what was sent
            if isinstance(step, Slow):
                step = step.message
            key = "EXPECT" if isinstance(step, Expect) else step.mnemonic
            plausible = ANSWERS.get(key, st.one_of(st.just(Ok()), refusal))
            answer = data.draw(st.one_of(plausible, plausible, plausible, anything))
            step = op.send(answer)
    except StopIteration:
        pass
    except DncError:
        pass
    finally:
        op.close()


@given(st.sampled_from(list(RunInfo)), st.binary(max_size=80))
def test_run_info_decoders(selector: RunInfo, data: bytes) -> None:
    with contextlib.suppress(RemoteProtocolError):
        decode_run_info(selector, data)


@given(st.text(max_size=300))
def test_table_parser_only_input_errors(text: str) -> None:
    with contextlib.suppress(InputError):
        parse_table(text)


@st.composite
def near_tables(draw: st.DrawFn) -> str:
    lines = ["BEGIN TOOL.T MM", "T    NAME    L"]
    lines += draw(st.lists(st.text(alphabet="0123456789+-. ABCxyz", max_size=20), max_size=5))
    if draw(st.booleans()):
        lines.append("[END]")
    return draw(st.sampled_from(["\n", "\r\n"])).join(lines)


@given(near_tables())
def test_near_valid_tables(text: str) -> None:
    try:
        table = parse_table(text)
    except InputError:
        return
    assert parse_table(table.to_text()).rows == table.rows


@given(st.text(max_size=12))
def test_operand_parser_only_input_errors(text: str) -> None:
    with contextlib.suppress(InputError):
        parse_operand(text)
