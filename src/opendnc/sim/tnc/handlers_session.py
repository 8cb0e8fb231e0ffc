"""Handlers for logins, versions, system parameters/information and system commands."""

from __future__ import annotations

import time

from opendnc.errors import ControlRefused
from opendnc.lsv2.constants import ErrorCode as E
from opendnc.lsv2.constants import Login as L
from opendnc.lsv2.messages import (
    CommandDone,
    DateTimeReply,
    Login,
    Logout,
    Message,
    ParametersReply,
    ReadDateTime,
    ReadParameters,
    ReadStatus,
    ReadSystemInfo,
    ReadVersion,
    SetStatus,
    StatusReply,
    SystemCommand,
    SystemInfoReply,
    VersionReply,
)
from opendnc.sim.tnc import oplog
from opendnc.sim.tnc.screen import render_status
from opendnc.sim.tnc.session import OK, Deferred, Priv, Result, Session, handler

PASSWORD_LOGINS = frozenset({L.FILEPLC, L.FILESYS, L.FILELOG, L.STREAMAXES})
OPLOG_DELAY = 0.2  # seconds until M_CC announces the finished log


@handler(Login, Priv.NONE)
def login(s: Session, m: Login) -> list[Message]:
    """A_LG name [password]: cumulative logins with the family's rules."""
    if not m.login:
        raise ControlRefused(E.T_ER_BAD_FORMAT)
    name = m.login.upper()
    password = m.password or ""
    c = s.control
    if name not in c.profile.logins:
        raise ControlRefused(E.T_ER_NO_LOGIN, f"{name} not available on {c.profile.key}")
    if name in PASSWORD_LOGINS and password != c.profile.plc_password:
        raise ControlRefused(E.T_ER_BAD_KEY, "wrong password")
    if name == L.DNC and not c.dnc_option:
        raise ControlRefused(E.T_ER_NO_LOGIN, "DNC option not set")
    if name == L.MONITOR:
        if c.monitor_owner not in (None, s.id):
            raise ControlRefused(E.T_ER_NO_LOGIN, "MONITOR held by another session")
        c.monitor_owner = s.id
    if name not in s.logins:
        c.log_event(f"LSV2 login {name} (session {s.id})")
    s.logins.add(name)
    return [OK]


@handler(Logout, Priv.NONE)
def logout(s: Session, m: Logout) -> list[Message]:
    """A_LO [name]: drop one login or all."""
    name = (m.login or "").upper()
    dropped = {name} if name else set(s.logins)
    s.logins -= dropped
    if "MONITOR" in dropped and s.control.monitor_owner == s.id:
        s.control.monitor_owner = None
    return [OK]


@handler(ReadVersion, Priv.INSPECT)
def versions(s: Session, m: ReadVersion) -> list[Message]:
    """R_VR: all strings, or one by selector byte."""
    p = s.control.profile
    if m.selector is None:
        return [VersionReply(tuple(p.version_parts()))]
    value = p.version_selector(m.selector)
    if value is None:
        raise ControlRefused(E.T_ER_WRONG_PARA)
    return [VersionReply((value,))]


@handler(ReadParameters, Priv.INSPECT)
def system_parameters(s: Session, m: ReadParameters) -> list[Message]:
    """R_PR: the family's 120/124-byte block."""
    return [ParametersReply(s.control.profile.parameters())]


@handler(ReadSystemInfo, Priv.ANY)
def system_info(s: Session, m: ReadSystemInfo) -> list[Message]:
    """R_CI selector: turbo (1), DNC allowed (2), axes sampling rate (3)."""
    if m.selector == 1:
        return [SystemInfoReply(1, 0)]
    if m.selector == 2:
        return [SystemInfoReply(1, 1 if s.control.dnc_option else 0)]
    if m.selector == 3 and s.control.profile.scope:
        return [SystemInfoReply(2, 3000)]
    raise ControlRefused(E.T_ER_WRONG_PARA)


@handler(ReadStatus, Priv.ANY)
def read_status(s: Session, m: ReadStatus) -> list[Message]:
    """R_ST: the 12-byte remote status (echo of the last C_ST)."""
    return [StatusReply(s.control.remote_status)]


@handler(SetStatus, Priv.ANY)
def set_status(s: Session, m: SetStatus) -> list[Message]:
    """C_ST: store 12 status bytes."""
    s.control.remote_status = m.status
    return [OK]


@handler(ReadDateTime, Priv.DIAGNOSTICS)
def read_time(s: Session, m: ReadDateTime) -> list[Message]:
    """R_DT: seconds since 1970 (not on families without a clock service)."""
    if not s.control.profile.date_time:
        raise ControlRefused(E.T_ER_WRONG_PARA)
    return [DateTimeReply(int(time.time()), bytes(4))]


@handler(SystemCommand, Priv.ANY)
def system_command(s: Session, m: SystemCommand) -> list[Message] | Result:
    """C_CC sub-command [parameter].

    Buffer sizes and secure file send take effect in the shared engine when it sends our
    ``T_OK``; here we only decide whether this family accepts the command.
    """
    sub = m.command
    param = m.parameter or ""
    p = s.control.profile
    if sub in p.buffer_sizes():
        return [OK]
    if sub not in p.system_commands:
        raise ControlRefused(E.T_ER_WRONG_PARA)
    if sub == 19:
        return [OK]
    if sub == 12:
        return screen_dump(s, param)
    if sub == 27:
        return operations_log(s, param)
    return [OK]  # stop time update, reset DNC, preset to log, observe-remove-all: no-ops


def screen_dump(s: Session, target: str) -> list[Message]:
    """C_CC 12: write a BMP of the status screen to ``target``."""
    if not ({"FILE", "MONITOR"} & s.logins):  # pyLSV2 uses FILE, the toolbox MONITOR
        raise ControlRefused(E.T_ER_NO_PRIV)
    if not target:
        raise ControlRefused(E.T_ER_BAD_FNAME)
    wp = s.path(target)
    s.control.fs.write_atomic(wp, render_status(s.control.machine))
    return [OK]


def operations_log(s: Session, param: str) -> Result:
    """C_CC 27: accept, then write the log and announce it with ``M_CC``
    (docs/lsv2.md#operations-log)."""
    if not s.allowed(Priv.FILE):
        raise ControlRefused(E.T_ER_NO_PRIV)
    request = oplog.parse_request(param)
    s.path(request.name)  # validate now so a bad name is refused up front
    cwd = s.cwd
    control = s.control

    def finish() -> Message | None:
        try:
            control.write_operations_log(request, cwd)
        except ControlRefused:
            return None
        return CommandDone(27, 100)

    return Result([OK], [Deferred(OPLOG_DELAY, finish)])
