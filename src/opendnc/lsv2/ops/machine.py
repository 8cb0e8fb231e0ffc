"""Machine operations: run-time state, NC errors, PLC memory, data paths, machine parameters,
keyboard, date/time."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from typing import TypeVar

from opendnc.errors import ControlRefused, RemoteProtocolError
from opendnc.lsv2.constants import (
    ExecutionMode,
    Login,
    MemoryType,
    ProgramState,
    RunInfo,
)
from opendnc.lsv2.messages import (
    DataPathReply,
    DateTimeReply,
    EmulateKey,
    LockKeyboard,
    MachineParameterReply,
    MemoryReply,
    ReadDataPath,
    ReadDateTime,
    ReadMachineParameter,
    ReadMemory,
    ReadRunInfo,
    Refused,
    RunInfoReply,
    WriteMachineParameter,
)
from opendnc.lsv2.ops.base import (
    Op,
    SessionState,
    Slow,
    ask,
    command,
    ensure_login,
    expect,
    require_unsafe,
)
from opendnc.lsv2.plc import PlcOperand, PlcValue, decode_values, parse_operand, plan_reads
from opendnc.lsv2.runinfo import (
    AxesConfig,
    AxesNames,
    AxesPositions,
    NcError,
    Overrides,
    RunInfoValue,
    SelectedProgram,
    ToolInfo,
)

__all__ = [
    "Uptimes",
    "axes_config",
    "axes_names",
    "axes_position",
    "current_tool",
    "date_time",
    "emulate_key",
    "execution_mode",
    "lock_keyboard",
    "nc_errors",
    "overrides",
    "program_state",
    "read_data_path",
    "read_machine_parameter",
    "read_plc",
    "read_plc_memory",
    "run_info",
    "selected_program",
    "uptimes",
    "write_machine_parameter",
]

V = TypeVar("V")

MP_WRITE_TIMEOUT = 30.0
"""Writing a machine parameter saves it to disk on the control: allow a long time."""


def run_info(state: SessionState, selector: int) -> Op[RunInfoValue]:
    """``R_RI``: run-time information, decoded by selector (login DNC)."""
    yield from ensure_login(state, Login.DNC)
    reply = yield from ask(ReadRunInfo(selector), RunInfoReply, f"run info {selector}")
    return reply.value(selector)


def _checked(value: RunInfoValue, kind: type[V], selector: int) -> V:
    """``value`` as ``kind``; the decoder picks the type by selector, so a mismatch is a bug
    or a control answering another selector: report it as a protocol error."""
    if not isinstance(value, kind):
        raise RemoteProtocolError(f"run info {selector}: expected {kind.__name__}, got {value!r}")
    return value


def _run_info_as(state: SessionState, selector: RunInfo, kind: type[V]) -> Op[V]:
    return _checked((yield from run_info(state, selector)), kind, selector)


def execution_mode(state: SessionState) -> Op[ExecutionMode]:
    """Operating mode (``R_RI`` 23)."""
    return (yield from _run_info_as(state, RunInfo.EXEC_STATE, ExecutionMode))


def program_state(state: SessionState) -> Op[ProgramState]:
    """Program state (``R_RI`` 26)."""
    return (yield from _run_info_as(state, RunInfo.PGM_STATE, ProgramState))


def selected_program(state: SessionState) -> Op[SelectedProgram]:
    """Selected main program, current (called) program and line (``R_RI`` 24)."""
    return (yield from _run_info_as(state, RunInfo.SELECTED_PGM, SelectedProgram))


def overrides(state: SessionState) -> Op[Overrides]:
    """Feed, spindle and rapid overrides (``R_RI`` 25)."""
    return (yield from _run_info_as(state, RunInfo.OVERRIDE, Overrides))


def axes_position(state: SessionState) -> Op[AxesPositions]:
    """Current axis positions (``R_RI`` 22)."""
    return (yield from _run_info_as(state, RunInfo.AXES_POSITION, AxesPositions))


def axes_names(state: SessionState) -> Op[AxesNames]:
    """Physical axis names (``R_RI`` 21)."""
    return (yield from _run_info_as(state, RunInfo.AXES_NAMES, AxesNames))


def axes_config(state: SessionState) -> Op[AxesConfig]:
    """Axis configuration (``R_RI`` 20)."""
    return (yield from _run_info_as(state, RunInfo.AXES_CONFIG, AxesConfig))


def current_tool(state: SessionState) -> Op[ToolInfo]:
    """The tool in the spindle (``R_RI`` 51, iTNC 530)."""
    return (yield from _run_info_as(state, RunInfo.CURRENT_TOOL, ToolInfo))


def nc_errors(state: SessionState) -> Op[list[NcError]]:
    """All pending NC error messages (``R_RI`` 27, then 28 until ``T_ER`` 57)."""
    yield from ensure_login(state, Login.DNC)
    errors: list[NcError] = []
    selector = RunInfo.FIRST_ERROR
    while True:
        reply = yield ReadRunInfo(selector)
        if isinstance(reply, Refused) and reply.code == 57:
            return errors
        value = expect(reply, RunInfoReply, f"NC error {selector}").value(selector)
        errors.append(_checked(value, NcError, selector))
        selector = RunInfo.NEXT_ERROR
        if len(errors) > 10_000:
            raise RemoteProtocolError("control keeps sending NC errors (no end marker 57)")


@dataclass(frozen=True, slots=True)
class Uptimes:
    """Time counters in seconds (``R_RI`` 30-34); ``None`` where unsupported."""

    nc: int | None
    machine: int | None
    machine_run: int | None
    spindle1: int | None
    spindle2: int | None


def uptimes(state: SessionState) -> Op[Uptimes]:
    """NC, machine, run-time and spindle counters."""
    yield from ensure_login(state, Login.DNC)
    values: list[int | None] = []
    for sel in (
        RunInfo.NC_UPTIME,
        RunInfo.MACHINE_UPTIME,
        RunInfo.MACHINE_RUNTIME,
        RunInfo.SPINDLE1_RUNTIME,
        RunInfo.SPINDLE2_RUNTIME,
    ):
        reply = yield ReadRunInfo(sel)
        if isinstance(reply, Refused):
            values.append(None)
            continue
        value = expect(reply, RunInfoReply, f"run info {sel}").value(sel)
        values.append(_checked(value, int, sel))
    return Uptimes(*values)


def read_plc_memory(
    state: SessionState, memory: MemoryType, index: int, count: int = 1
) -> Op[list[PlcValue]]:
    """Read ``count`` elements of ``memory`` from element ``index`` (login PLCDEBUG)."""
    params = state.require_params()
    plan = plan_reads(memory, index, count, params)
    yield from ensure_login(state, Login.PLCDEBUG)
    chunks: list[bytes] = []
    for address, size in plan:
        reply = yield from ask(ReadMemory(address, size), MemoryReply, f"read PLC {address}")
        if len(reply.data) != size:
            raise RemoteProtocolError(f"S_MB returned {len(reply.data)} bytes, asked {size}")
        chunks.append(reply.data)
    return decode_values(memory, b"".join(chunks), count, params)


def read_plc(state: SessionState, operand: str | PlcOperand, count: int = 1) -> Op[list[PlcValue]]:
    """Read by operand notation, e.g. ``read_plc(state, "W4", 3)``."""
    op = parse_operand(operand) if isinstance(operand, str) else operand
    return (yield from read_plc_memory(state, op.memory, op.index, count))


def read_data_path(state: SessionState, path: str) -> Op[int | float | str | bool]:
    """``R_DP``: a value by data path (iTNC 530; login DATA)."""
    yield from ensure_login(state, Login.DATA)
    wire = path.replace("/", "\\").replace('"', "'")
    reply = yield from ask(ReadDataPath(wire), DataPathReply, f"data path {path}")
    return reply.value


def read_machine_parameter(state: SessionState, name: str) -> Op[str]:
    """``R_MC``: a machine parameter's value as text."""
    yield from ensure_login(state, Login.INSPECT)
    reply = yield from ask(
        ReadMachineParameter(name), MachineParameterReply, f"machine parameter {name}"
    )
    return reply.value


def write_machine_parameter(
    state: SessionState, name: str, value: str, *, temporary: bool = False
) -> Op[None]:
    """``C_MC``: write a machine parameter (unsafe; login PLCDEBUG)."""
    require_unsafe(state, f"writing machine parameter {name}")
    yield from ensure_login(state, Login.PLCDEBUG)
    msg = WriteMachineParameter(name, value, 1 if temporary else 0)
    yield from command(Slow(msg, MP_WRITE_TIMEOUT), f"write machine parameter {name}")


def lock_keyboard(state: SessionState, locked: bool) -> Op[None]:
    """``C_LK``: lock or unlock the control's keyboard (unsafe; login MONITOR)."""
    require_unsafe(state, "locking the control keyboard")
    yield from ensure_login(state, Login.MONITOR)
    yield from command(LockKeyboard(locked), "lock keyboard")


def emulate_key(state: SessionState, code: int, *, lock: bool = True) -> Op[None]:
    """``C_EK``: press a key (unsafe; login MONITOR), with the keyboard locked meanwhile."""
    require_unsafe(state, f"sending key 0x{code:04X}")
    yield from ensure_login(state, Login.MONITOR)
    if lock:
        yield from command(LockKeyboard(True), "lock keyboard")
    try:
        yield from command(EmulateKey(code), f"key 0x{code:04X}")
    except ControlRefused:
        if lock:
            yield from command(LockKeyboard(False), "unlock keyboard")
        raise
    if lock:
        yield from command(LockKeyboard(False), "unlock keyboard")


def date_time(state: SessionState) -> Op[datetime]:
    """``R_DT``: the control's clock (login DIAGNOSTICS)."""
    yield from ensure_login(state, Login.DIAGNOSTICS)
    reply = yield from ask(ReadDateTime(), DateTimeReply, "read date and time")
    return datetime.fromtimestamp(reply.timestamp, UTC)
