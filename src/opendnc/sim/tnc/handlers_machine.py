"""Handlers for machine state: run-time info, PLC memory, data paths, parameters, keys, scope."""

from __future__ import annotations

import itertools
import struct
from collections.abc import Iterator

from opendnc.lsv2.constants import ErrorCode as E
from opendnc.lsv2.framing import Frame
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
from opendnc.sim.tnc.machine import MachineError
from opendnc.sim.tnc.plc import PlcError, resolve_data_path
from opendnc.sim.tnc.session import OK, Priv, Refuse, Session, handler

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
            raise Refuse(E.T_ER_NO_NEXT_ERROR)
        e = m.errors[s.error_index]
        s.error_index += 1
        return encode_run_info(selector, NcError(e.error_class, e.group, e.number, e.text))
    if selector in (30, 31, 32, 33, 34):
        return encode_run_info(selector, m.uptimes()[selector])
    if selector == 51:
        number, index, axis, length, radius = m.tool_info()
        return encode_run_info(selector, ToolInfo(number, index, axis, length, radius))
    raise Refuse(E.T_ER_WRONG_PARA)


@handler("R_RI", Priv.INSPECT)
def run_info(s: Session, f: Frame) -> list[Frame]:
    """R_RI u16 selector (DNC login; selectors per family)."""
    if len(f.payload) != 2:
        raise Refuse(E.T_ER_BAD_FORMAT)
    (selector,) = struct.unpack(">H", f.payload)
    if selector not in s.control.profile.ri_selectors:
        raise Refuse(E.T_ER_WRONG_PARA)
    if "DNC" not in s.logins:
        raise Refuse(E.T_ER_NO_PRIV)
    return [Frame("S_RI", _run_info(s, selector))]


@handler("R_MB", Priv.INSPECT)
def read_memory(s: Session, f: Frame) -> list[Frame]:
    """R_MB u32 address + u8 count: raw bytes of the PLC image."""
    if len(f.payload) != 5:
        raise Refuse(E.T_ER_BAD_FORMAT)
    address, count = struct.unpack(">IB", f.payload)
    s.control.machine.advance()
    try:
        return [Frame("S_MB", s.control.plc.read(address, count))]
    except PlcError as exc:
        raise Refuse(exc.code) from None


@handler("R_DP", Priv.DATA)
def read_data_path(s: Session, f: Frame) -> list[Frame]:
    """R_DP 4 bytes + cstr path (iTNC only)."""
    if not s.control.profile.data_paths:
        raise Refuse(E.T_ER_UNKNOWN_TELE)
    if len(f.payload) < 5:
        raise Refuse(E.T_ER_BAD_FORMAT)
    path = read_cstr(f.payload, 4)[0]
    s.control.machine.advance()
    try:
        value = resolve_data_path(path, s.control.plc, s.control.tool_rows())
    except PlcError as exc:
        raise Refuse(exc.code) from None
    return [Frame("S_DP", value.encode())]


@handler("R_MC", Priv.INSPECT)
def read_parameter(s: Session, f: Frame) -> list[Frame]:
    """R_MC name -> S_MC value."""
    value = s.control.mp.read(read_cstr(f.payload)[0])
    if value is None:
        raise Refuse(E.T_ER_NO_MP)
    return [Frame("S_MC", value.encode("latin-1", "replace") + b"\0")]


@handler("C_MC", Priv.PLCDEBUG)
def write_parameter(s: Session, f: Frame) -> list[Frame]:
    """C_MC u32 flags + name + value (flag 1 = temporary)."""
    if len(f.payload) < 6:
        raise Refuse(E.T_ER_BAD_FORMAT)
    (flags,) = struct.unpack_from(">I", f.payload)
    name, end = read_cstr(f.payload, 4)
    value = read_cstr(f.payload, end)[0] if end < len(f.payload) else ""
    if not s.control.mp.write(name, value, temporary=bool(flags & 1)):
        raise Refuse(E.T_ER_NO_MP)
    s.control.log_event(f"Machine parameter {name} = {value}")
    return [OK]


@handler("C_LK", Priv.MONITOR)
def lock_keyboard(s: Session, f: Frame) -> list[Frame]:
    """C_LK u8: 1 lock, 0 unlock the control's own keyboard."""
    if s.control.profile.keys.value == "none":
        raise Refuse(E.T_ER_UNKNOWN_TELE)
    if len(f.payload) != 1 or f.payload[0] not in (0, 1, 0x30, 0x31):
        raise Refuse(E.T_ER_BAD_FORMAT)
    s.keyboard_locked = f.payload[0] in (1, 0x31)
    s.control.machine.keyboard_locked = s.keyboard_locked
    return [OK]


@handler("C_EK", Priv.MONITOR)
def emulate_key(s: Session, f: Frame) -> list[Frame]:
    """C_EK u16 key code."""
    if len(f.payload) != 2:
        raise Refuse(E.T_ER_BAD_FORMAT)
    (code,) = struct.unpack(">H", f.payload)
    try:
        s.control.machine.press_key(code)
    except MachineError as exc:
        raise Refuse(exc.code) from None
    return [OK]


@handler("C_NC", Priv.DNC)
def select_program(s: Session, f: Frame) -> list[Frame]:
    """C_NC path: select an NC program for execution (DNC)."""
    wp = s.path(read_cstr(f.payload)[0])
    try:
        s.control.select_program(wp)
    except MachineError as exc:
        raise Refuse(exc.code) from None
    return [OK]


@handler("C_CN", Priv.DNC)
def cancel_program(s: Session, f: Frame) -> list[Frame]:
    """C_CN: cancel the running program."""
    s.control.machine.cancel()
    return [OK]


# -- scope ------------------------------------------------------------------------------------
@handler("R_OC", Priv.OSZI)
def scope_channels(s: Session, f: Frame) -> list[Frame]:
    """R_OC: one S_OC per T_OK, then T_FD."""
    return s.start_sequence(Frame("S_OC", c.describe()) for c in scope.CHANNELS)


@handler("R_OP", Priv.OSZI)
def scope_select(s: Session, f: Frame) -> list[Frame]:
    """R_OP interval + selectors -> S_OP signal details."""
    try:
        interval, signals = scope.parse_selection(f.payload)
    except ValueError as exc:
        raise Refuse(int(exc.args[0])) from None
    s.scope_signals = list(signals)
    s.scope_interval = interval
    return [Frame("S_OP", scope.signal_details(signals))]


@handler("R_OD", Priv.OSZI)
def scope_data(s: Session, f: Frame) -> list[Frame]:
    """R_OD trigger block: stream S_OD blocks, one per T_OK, until another telegram."""
    signals = [x for x in s.scope_signals if isinstance(x, scope.Signal)]
    if not signals or len(f.payload) != 16:
        raise Refuse(E.T_ER_OSZI_CHSEL)
    machine = s.control.machine
    interval = s.scope_interval

    def stream() -> Iterator[Frame]:
        for seq in itertools.count():
            yield Frame("S_OD", scope.sample_block(machine, signals, seq, interval))

    return s.start_sequence(stream())
