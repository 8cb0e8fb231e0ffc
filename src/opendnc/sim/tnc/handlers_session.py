"""Handlers for logins, versions, system parameters/information and system commands."""

from __future__ import annotations

import struct
import time

from opendnc.lsv2.constants import ErrorCode as E
from opendnc.lsv2.framing import Frame
from opendnc.lsv2.payloads import read_cstr, split_cstrs
from opendnc.sim.tnc import oplog
from opendnc.sim.tnc.filesystem import FsError
from opendnc.sim.tnc.screen import render_status
from opendnc.sim.tnc.session import OK, Deferred, Priv, Refuse, Result, Session, handler

PASSWORD_LOGINS = frozenset({"FILEPLC", "FILESYS", "FILELOG", "STREAMAXES"})
OPLOG_DELAY = 0.2  # seconds until M_CC announces the finished log


@handler("A_LG", Priv.NONE)
def login(s: Session, f: Frame) -> list[Frame]:
    """A_LG name [password]: cumulative logins with the family's rules."""
    parts = split_cstrs(f.payload)
    if not parts or not parts[0]:
        raise Refuse(E.T_ER_BAD_FORMAT)
    name = parts[0].upper()
    password = parts[1] if len(parts) > 1 else ""
    c = s.control
    if name not in c.profile.logins:
        raise Refuse(E.T_ER_NO_LOGIN, f"{name} not available on {c.profile.key}")
    if name in PASSWORD_LOGINS and password != c.profile.plc_password:
        raise Refuse(E.T_ER_BAD_KEY, "wrong password")
    if name == "DNC" and not c.dnc_option:
        raise Refuse(E.T_ER_NO_LOGIN, "DNC option not set")
    if name == "MONITOR":
        if c.monitor_owner not in (None, s.id):
            raise Refuse(E.T_ER_NO_LOGIN, "MONITOR held by another session")
        c.monitor_owner = s.id
    s.logins.add(name)
    return [OK]


@handler("A_LO", Priv.NONE)
def logout(s: Session, f: Frame) -> list[Frame]:
    """A_LO [name]: drop one login or all."""
    name = read_cstr(f.payload)[0].upper() if f.payload.strip(b"\0") else ""
    dropped = {name} if name else set(s.logins)
    s.logins -= dropped
    if "MONITOR" in dropped and s.control.monitor_owner == s.id:
        s.control.monitor_owner = None
    return [OK]


@handler("R_VR", Priv.INSPECT)
def versions(s: Session, f: Frame) -> list[Frame]:
    """R_VR: all strings, or one by selector byte."""
    p = s.control.profile
    if not f.payload:
        return [Frame("S_VR", b"".join(x.encode("latin-1") + b"\0" for x in p.version_parts()))]
    value = p.version_selector(f.payload[0])
    if value is None or len(f.payload) != 1:
        raise Refuse(E.T_ER_WRONG_PARA)
    return [Frame("S_VR", value.encode("latin-1") + b"\0")]


@handler("R_PR", Priv.INSPECT)
def system_parameters(s: Session, f: Frame) -> list[Frame]:
    """R_PR: the family's 120/124-byte block."""
    return [Frame("S_PR", s.control.profile.system_parameters())]


@handler("R_CI", Priv.ANY)
def system_info(s: Session, f: Frame) -> list[Frame]:
    """R_CI selector: turbo (1), DNC allowed (2), axes sampling rate (3)."""
    if len(f.payload) != 4:
        raise Refuse(E.T_ER_BAD_FORMAT)
    (selector,) = struct.unpack(">I", f.payload)
    if selector == 1:
        return [Frame("S_CI", struct.pack(">II", 1, 0))]
    if selector == 2:
        return [Frame("S_CI", struct.pack(">II", 1, 1 if s.control.dnc_option else 0))]
    if selector == 3 and s.control.profile.scope:
        return [Frame("S_CI", struct.pack(">II", 2, 3000))]
    raise Refuse(E.T_ER_WRONG_PARA)


@handler("R_ST", Priv.ANY)
def read_status(s: Session, f: Frame) -> list[Frame]:
    """R_ST: the 12-byte remote status (echo of the last C_ST)."""
    return [Frame("S_ST", s.control.remote_status)]


@handler("C_ST", Priv.ANY)
def set_status(s: Session, f: Frame) -> list[Frame]:
    """C_ST: store 12 status bytes."""
    if len(f.payload) != 12:
        raise Refuse(E.T_ER_BAD_FORMAT)
    s.control.remote_status = f.payload
    return [OK]


@handler("R_DT", Priv.DIAGNOSTICS)
def read_time(s: Session, f: Frame) -> list[Frame]:
    """R_DT: seconds since 1970 (not on families without a clock service)."""
    if not s.control.profile.date_time:
        raise Refuse(E.T_ER_WRONG_PARA)
    return [Frame("S_DT", struct.pack(">I", int(time.time())) + bytes(4))]


@handler("C_CC", Priv.ANY)
def system_command(s: Session, f: Frame) -> list[Frame] | Result:
    """C_CC sub-command [parameter]."""
    if len(f.payload) < 2:
        raise Refuse(E.T_ER_BAD_FORMAT)
    (sub,) = struct.unpack_from(">H", f.payload)
    param = read_cstr(f.payload, 2)[0] if len(f.payload) > 2 else ""
    p = s.control.profile
    sizes = p.buffer_sizes()
    if sub in sizes:
        s.buffer_size = sizes[sub]
        return [OK]
    if sub not in p.system_commands:
        raise Refuse(E.T_ER_WRONG_PARA)
    if sub == 19:
        s.secure_send = True
        return [OK]
    if sub == 12:
        return screen_dump(s, param)
    if sub == 27:
        return operations_log(s, param)
    return [OK]  # stop time update, reset DNC, preset to log, observe-remove-all: no-ops


def screen_dump(s: Session, target: str) -> list[Frame]:
    """C_CC 12: write a BMP of the status screen to ``target``."""
    if not s.allowed(Priv.MONITOR):
        raise Refuse(E.T_ER_NO_PRIV)
    if not target:
        raise Refuse(E.T_ER_BAD_FNAME)
    wp = s.path(target)
    s.control.fs.write_atomic(wp, render_status(s.control.machine))
    return [OK]


def operations_log(s: Session, param: str) -> Result:
    """C_CC 27: accept, then write the log and announce it with ``M_CC`` (§5.5)."""
    if not s.allowed(Priv.FILE):
        raise Refuse(E.T_ER_NO_PRIV)
    try:
        request = oplog.parse_request(param)
    except ValueError:
        raise Refuse(E.T_ER_BAD_PARAMETER) from None
    s.path(request.name)  # validate now so a bad name is refused up front
    cwd = s.cwd
    control = s.control

    def finish() -> Frame | None:
        try:
            control.write_operations_log(request, cwd)
        except FsError:
            return None
        return Frame("M_CC", struct.pack(">HH", 27, 100))

    return Result([OK], [Deferred(OPLOG_DELAY, finish)])
