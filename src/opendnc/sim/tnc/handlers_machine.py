"""Handlers for machine state: run-time info, PLC memory, data paths, parameters, keys, scope."""

from __future__ import annotations

import itertools
from collections.abc import Iterator

from opendnc.errors import ControlRefused
from opendnc.lsv2.constants import ErrorCode as E
from opendnc.lsv2.messages import (
    EmulateKey,
    LockKeyboard,
    MachineParameterReply,
    MemoryReply,
    Message,
    Opaque,
    ReadDataPath,
    ReadMachineParameter,
    ReadMemory,
    ReadRunInfo,
    ReadScopeChannels,
    RunInfoReply,
    ScopeChannelReply,
    ScopeDataReply,
    ScopeSelect,
    ScopeSignalReply,
    ScopeStart,
    WriteMachineParameter,
)
from opendnc.lsv2.payloads import read_cstr
from opendnc.lsv2.runinfo import (
    AxesConfig,
    AxesNames,
    AxesPositions,
    AxisConfig,
    AxisName,
    AxisPosition,
    NcError,
    Overrides,
    SelectedProgram,
    ToolInfo,
    encode_run_info,
)
from opendnc.sim.tnc import scope
from opendnc.sim.tnc.plc import resolve_data_path
from opendnc.sim.tnc.session import OK, Priv, Session, handler

_AXIS_IDS = {"X": 0, "Y": 1, "Z": 2, "A": 3, "B": 4, "C": 5, "U": 6, "V": 7, "W": 8}


def _run_info(s: Session, selector: int) -> bytes:
    m = s.control.machine
    m.advance()
    if selector == 20:
        cfg = AxesConfig(tuple(AxisConfig(_AXIS_IDS[a], 1, a) for a in m.positions))
        return encode_run_info(selector, cfg)
    if selector == 21:
        names = AxesNames(tuple(AxisName(_AXIS_IDS[a], a, a) for a in m.positions))
        return encode_run_info(selector, names)
    if selector == 22:
        axes = tuple(AxisPosition(a, f"{v:.4f}") for a, v in m.positions.items())
        return encode_run_info(selector, AxesPositions(axes))
    if selector == 23:
        return encode_run_info(selector, int(m.exec_mode))
    if selector == 24:
        return encode_run_info(
            selector, SelectedProgram(m.main_program, m.current_program, m.current_line)
        )
    if selector == 25:
        return encode_run_info(
            selector, Overrides(m.feed_override, m.spindle_override, m.rapid_override)
        )
    if selector == 26:
        return encode_run_info(selector, int(m.program_state))
    if selector in (27, 28):
        if selector == 27:
            s.error_index = 0
        if s.error_index >= len(m.errors):
            raise ControlRefused(E.T_ER_NO_NEXT_ERROR)
        e = m.errors[s.error_index]
        s.error_index += 1
        return encode_run_info(selector, NcError(e.error_class, e.group, e.number, e.text))
    if selector in (30, 31, 32, 33, 34):
        return encode_run_info(selector, m.uptimes()[selector])
    if selector == 51:
        number, index, axis, length, radius = m.tool_info()
        return encode_run_info(selector, ToolInfo(number, index, axis, length, radius))
    raise ControlRefused(E.T_ER_WRONG_PARA)


@handler(ReadRunInfo, Priv.INSPECT)
def run_info(s: Session, m: ReadRunInfo) -> list[Message]:
    """R_RI u16 selector (DNC login; selectors per family)."""
    if m.selector not in s.control.profile.ri_selectors:
        raise ControlRefused(E.T_ER_WRONG_PARA)
    if "DNC" not in s.logins:
        raise ControlRefused(E.T_ER_NO_PRIV)
    return [RunInfoReply(_run_info(s, m.selector))]


@handler(ReadMemory, Priv.INSPECT)
def read_memory(s: Session, m: ReadMemory) -> list[Message]:
    """R_MB u32 address + u8 count: raw bytes of the PLC image."""
    s.control.machine.advance()
    return [MemoryReply(s.control.plc.read(m.address, m.count))]


@handler(ReadDataPath, Priv.DATA)
def read_data_path(s: Session, m: ReadDataPath) -> list[Message]:
    """R_DP path (iTNC only)."""
    if not s.control.profile.data_paths:
        raise ControlRefused(E.T_ER_UNKNOWN_TELE)
    s.control.machine.advance()
    return [resolve_data_path(m.path, s.control.plc, s.control.tool_rows())]


@handler(ReadMachineParameter, Priv.INSPECT)
def read_parameter(s: Session, m: ReadMachineParameter) -> list[Message]:
    """R_MC name -> S_MC value."""
    value = s.control.mp.read(m.name)
    if value is None:
        raise ControlRefused(E.T_ER_NO_MP)
    return [MachineParameterReply(value.encode("latin-1", "replace").decode("latin-1"))]


@handler(WriteMachineParameter, Priv.PLCDEBUG)
def write_parameter(s: Session, m: WriteMachineParameter) -> list[Message]:
    """C_MC flags name value (flag 1 = temporary until restart)."""
    if not s.control.mp.write(m.name, m.value, temporary=bool(m.flags & 1)):
        raise ControlRefused(E.T_ER_NO_MP)
    s.control.log_event(f"Machine parameter {m.name} = {m.value}")
    return [OK]


@handler(LockKeyboard, Priv.MONITOR)
def lock_keyboard(s: Session, m: LockKeyboard) -> list[Message]:
    """C_LK: lock or unlock the control's own keyboard."""
    if s.control.profile.keys.value == "none":
        raise ControlRefused(E.T_ER_UNKNOWN_TELE)
    s.keyboard_locked = m.locked
    s.control.machine.keyboard_locked = m.locked
    return [OK]


@handler(EmulateKey, Priv.MONITOR)
def emulate_key(s: Session, m: EmulateKey) -> list[Message]:
    """C_EK u16 key code."""
    s.control.machine.press_key(m.code)
    return [OK]


@handler("C_NC", Priv.DNC)
def select_program(s: Session, m: Opaque) -> list[Message]:
    """C_NC path: select an NC program for execution (DNC; layout assumed: one cstr)."""
    # DNC selects programs without the FILE login, so no drive-login check here.
    wp = s.control.fs.parse(read_cstr(m.payload)[0], s.cwd)
    s.control.select_program(wp)
    return [OK]


@handler("C_CN", Priv.DNC)
def cancel_program(s: Session, m: Opaque) -> list[Message]:
    """C_CN: cancel the running program."""
    s.control.machine.cancel()
    return [OK]


# -- scope ------------------------------------------------------------------------------------
@handler(ReadScopeChannels, Priv.OSZI)
def scope_channels(s: Session, m: ReadScopeChannels) -> list[Message]:
    """R_OC: one S_OC per T_OK, then T_FD."""
    return s.start_sequence(ScopeChannelReply(c.describe()) for c in scope.CHANNELS)


@handler(ScopeSelect, Priv.OSZI)
def scope_select(s: Session, m: ScopeSelect) -> list[Message]:
    """R_OP interval + selectors -> S_OP signal details."""
    if m.interval not in scope.INTERVALS:
        raise ControlRefused(E.T_ER_OSZI_CHSEL)
    signals = scope.parse_selection(m.signals)
    s.scope_signals = signals
    s.scope_interval = m.interval
    return [ScopeSignalReply(scope.signal_details(signals))]


@handler(ScopeStart, Priv.OSZI)
def scope_data(s: Session, m: ScopeStart) -> list[Message]:
    """R_OD trigger block: stream S_OD blocks, one per T_OK, until another telegram."""
    signals = list(s.scope_signals)
    if not signals:
        raise ControlRefused(E.T_ER_OSZI_CHSEL)
    machine = s.control.machine
    interval = s.scope_interval

    def stream() -> Iterator[Message]:
        for seq in itertools.count():
            yield ScopeDataReply(seq, scope.sample_blocks(machine, signals, seq, interval))

    return s.start_sequence(stream())
