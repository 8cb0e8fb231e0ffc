"""Composite operations: screen dump, operations log, remote scope, tool/pocket tables."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime

from opendnc.errors import ControlRefused, RemoteProtocolError
from opendnc.lsv2.constants import CcCommand, Family, Login, SystemInfoSelector
from opendnc.lsv2.messages import (
    BlockDefect,
    CommandDone,
    FileDone,
    Message,
    Ok,
    ReadScopeChannels,
    ReadStatus,
    ScopeChannelReply,
    ScopeDataReply,
    ScopeSelect,
    ScopeSignalReply,
    ScopeStart,
    SetStatus,
    StatusReply,
    SystemCommand,
)
from opendnc.lsv2.ops.base import (
    Expect,
    Op,
    SessionState,
    ask,
    command,
    ensure_login,
    expect,
    refuse,
    require_unsafe,
)
from opendnc.lsv2.ops.files import delete_file, download, upload
from opendnc.lsv2.ops.session import read_system_info
from opendnc.lsv2.payloads import ScopeChannel, ScopeSignal, ScopeSignalInfo
from opendnc.lsv2.tables import Table, parse_table

__all__ = [
    "ScopeRecording",
    "operations_log",
    "read_table",
    "scope_channels",
    "scope_record",
    "screen_dump",
    "table_paths",
    "write_table",
]

OPLOG_TIMEOUT = 120.0
"""Generating the operations log can take a while on a real control."""


def _download_bytes(state: SessionState, path: str, *, binary: bool = True) -> Op[bytes]:
    parts: list[bytes] = []
    yield from download(state, path, parts.append, binary=binary)
    return b"".join(parts)


def screen_dump(state: SessionState, *, stamp: datetime) -> Op[bytes]:
    """``C_CC`` 12 into a temporary BMP on the control, download it, delete it."""
    yield from ensure_login(state, Login.FILE)
    path = f"TNC:\\screendump_{stamp:%Y%m%d_%H%M%S}.bmp"
    yield from command(SystemCommand(CcCommand.SCREENDUMP, path), "screen dump")
    try:
        data = yield from _download_bytes(state, path)
    except ControlRefused:
        yield from delete_file(state, path, missing_ok=True)
        raise
    yield from delete_file(state, path, missing_ok=True)
    return data


def operations_log(
    state: SessionState, *, since: datetime, name: str = "operation.log"
) -> Op[bytes]:
    """Have the control write its operations log since ``since`` and download it
    (docs/lsv2.md#operations-log)."""
    yield from ensure_login(state, Login.FILE)
    status = yield from ask(ReadStatus(), StatusReply, "read remote status")
    yield from command(SetStatus(status.status), "set remote status")
    param = f"{name};{since:%d.%m.%Y};{since:%H:%M:%S};"
    yield from command(SystemCommand(CcCommand.GENERATE_OP_LOG, param), "generate operations log")
    while True:
        notice = yield Expect(OPLOG_TIMEOUT)
        if isinstance(notice, CommandDone) and notice.command == CcCommand.GENERATE_OP_LOG:
            break
    yield from command(SetStatus(status.status), "restore remote status")
    return (yield from _download_bytes(state, f"TNC:\\{name}"))


TABLE_PATHS: dict[Family, tuple[str, str]] = {
    Family.ITNC530: ("TNC:\\TOOL.T", "TNC:\\TOOL_P.TCH"),
    Family.TNC4XX: ("TNC:\\TOOL.T", "TNC:\\TOOL_P.TCH"),
    Family.LATHE_NEW: ("TNC:\\table\\toolturn.htt", "TNC:\\table\\ToolAllo.tch"),
}
"""Tool and pocket table of each family (others: ``TNC:\\table\\tool.t`` / ``tool_p.tch``)."""


def table_paths(family: Family) -> tuple[str, str]:
    """(tool table, pocket table) paths for ``family``."""
    return TABLE_PATHS.get(family, ("TNC:\\table\\tool.t", "TNC:\\table\\tool_p.tch"))


def read_table(state: SessionState, path: str) -> Op[Table]:
    """Download and parse a tool / pocket / other table file."""
    raw = yield from _download_bytes(state, path)
    return parse_table(raw.decode("latin-1"))


def write_table(state: SessionState, path: str, table: Table) -> Op[None]:
    """Upload ``table`` to ``path`` (unsafe: tables steer the machine)."""
    require_unsafe(state, f"writing table {path}")
    data = table.to_text().encode("latin-1")
    yield from upload(state, path, data, binary=True)


def _collect_channels(first: Message | None) -> Op[list[ScopeChannel]]:
    channels: list[ScopeChannel] = []
    reply = first
    while not isinstance(reply, FileDone):
        channels.append(expect(reply, ScopeChannelReply, "list scope channels").channel)
        reply = yield Ok()
    return channels


def scope_channels(state: SessionState) -> Op[list[ScopeChannel]]:
    """``R_OC``: the scope channels (iTNC 530; login OSZI)."""
    yield from ensure_login(state, Login.OSZI)
    reply = yield ReadScopeChannels()
    return (yield from _collect_channels(reply))


@dataclass(frozen=True, slots=True)
class ScopeRecording:
    """Recorded scope samples, scaled: ``values[i]`` is the series of signal ``i``."""

    interval: int
    """Sampling interval in µs."""
    signals: tuple[ScopeSignal, ...]
    info: tuple[ScopeSignalInfo, ...]
    values: tuple[tuple[float, ...], ...]


def scope_record(
    state: SessionState, signals: list[ScopeSignal], *, interval: int, blocks: int
) -> Op[ScopeRecording]:
    """Record ``blocks`` × 32 samples of ``signals`` (``R_OP``, ``R_OD``, ``T_OK``…, ``T_BD``)."""
    if state.family not in (Family.ITNC530, Family.UNKNOWN):
        raise ControlRefused(83, "remote scope works on the iTNC 530 only", context="scope")
    yield from ensure_login(state, Login.OSZI)
    yield from read_system_info(state, SystemInfoSelector.AXES_SAMPLING_RATE)
    selected = yield from ask(
        ScopeSelect(interval, tuple(signals)), ScopeSignalReply, "select scope signals"
    )
    if len(selected.signals) != len(signals):
        raise RemoteProtocolError(
            f"S_OP describes {len(selected.signals)} signals, {len(signals)} selected"
        )
    series: list[list[float]] = [[] for _ in signals]
    reply = yield ScopeStart(interval)
    for n in range(blocks):
        if not isinstance(reply, ScopeDataReply):
            refuse(reply, "scope recording")
        for i, (block, info) in enumerate(zip(reply.blocks, selected.signals, strict=False)):
            series[i].extend(s * info.factor + info.offset for s in block.samples[: block.count])
        if n + 1 < blocks:
            reply = yield Ok()
    yield BlockDefect()  # stop the stream; no answer follows
    return ScopeRecording(
        interval, tuple(signals), selected.signals, tuple(tuple(s) for s in series)
    )
