"""Session operations: connect sequence, logins, versions, parameters, system information."""

from __future__ import annotations

from dataclasses import dataclass, replace

from opendnc.lsv2.constants import (
    BUFFER_COMMANDS,
    CcCommand,
    Family,
    Login,
    SystemInfoSelector,
    SystemInfoType,
    VersionSelector,
    detect_family,
)
from opendnc.lsv2.framing import HEADER_SIZE
from opendnc.lsv2.messages import (
    Logout,
    ParametersReply,
    ReadParameters,
    ReadSystemInfo,
    ReadVersion,
    Refused,
    SystemCommand,
    SystemInfoReply,
    VersionReply,
)
from opendnc.lsv2.ops.base import (
    Op,
    SessionState,
    ask,
    command,
    ensure_login,
    expect,
    require_unsafe,
    try_command,
)
from opendnc.lsv2.payloads import SystemParameters, Versions

__all__ = [
    "MACHINE_LOGINS",
    "SystemInfo",
    "connect",
    "login",
    "logout",
    "negotiate_buffer",
    "read_parameters",
    "read_system_info",
    "read_version",
    "read_versions",
    "system_info_all",
]


def read_versions(state: SessionState) -> Op[Versions]:
    """The empty ``R_VR``: model, NC software, PLC, (SPLC,) options."""
    yield from ensure_login(state, Login.INSPECT)
    reply = yield from ask(ReadVersion(), VersionReply, "read versions")
    return Versions.from_parts(reply.parts)


def read_version(state: SessionState, selector: int) -> Op[str | None]:
    """One version string by selector; ``None`` if the control does not support it."""
    yield from ensure_login(state, Login.INSPECT)
    reply = yield ReadVersion(selector)
    if isinstance(reply, Refused):
        return None
    answer = expect(reply, VersionReply, f"read version {selector}")
    return answer.parts[0] if answer.parts else ""


def read_parameters(state: SessionState) -> Op[SystemParameters]:
    """``R_PR``: the system parameters."""
    yield from ensure_login(state, Login.INSPECT)
    reply = yield from ask(ReadParameters(), ParametersReply, "read system parameters")
    return reply.params


def read_system_info(state: SessionState, selector: int) -> Op[int | bool | None]:
    """``R_CI``: boolean or number, ``None`` when unsupported."""
    yield from ensure_login(state, Login.INSPECT)
    reply = yield ReadSystemInfo(selector)
    if isinstance(reply, Refused):
        return None
    info = expect(reply, SystemInfoReply, f"read system info {selector}")
    if info.value_type == SystemInfoType.BOOLEAN:
        return bool(info.value & 0xFF)
    return info.value


def negotiate_buffer(state: SessionState, limit: int) -> Op[int]:
    """Switch to the largest buffer allowed by ``limit`` and the control, falling back to
    smaller sizes when one is refused; returns the size in effect."""
    for size in sorted(BUFFER_COMMANDS, reverse=True):
        if size > limit or size <= state.buffer_size:
            continue
        if (yield from try_command(SystemCommand(BUFFER_COMMANDS[size]), f"buffer {size}")):
            state.buffer_size = size
            break
    return state.buffer_size


def connect(state: SessionState, *, max_buffer: int = 4096, secure_send: bool = True) -> Op[None]:
    """The start-up sequence: INSPECT, versions, parameters, buffer size, secure file send."""
    versions = yield from read_versions(state)
    family = detect_family(versions.model)
    # TNC 4xx answers only the empty R_VR; the extra selectors exist on newer software.
    if family is not Family.TNC4XX:
        control_id = yield from read_version(state, VersionSelector.ID)
        release = None
        if family is not Family.ITNC530:  # iTNC refuses selector 6
            release = yield from read_version(state, VersionSelector.RELEASE_TYPE)
        splc = versions.splc
        if splc is None:
            splc = yield from read_version(state, VersionSelector.SPLC)
        versions = replace(versions, control_id=control_id, release_type=release, splc=splc)
    state.versions = versions
    state.family = family
    state.params = yield from read_parameters(state)
    # max_block_length counts payload bytes: the one real capture (TNC 320 v18) advertises
    # 4088 = 4096 - 8 header bytes, so a 4096-byte telegram buffer fits. A control that
    # disagrees refuses the C_CC and negotiate_buffer falls back to the next smaller size.
    limit = state.params.max_block_length + HEADER_SIZE
    yield from negotiate_buffer(state, min(max_buffer, limit))
    if secure_send:
        state.secure_send = yield from try_command(
            SystemCommand(CcCommand.SECURE_FILE_SEND), "secure file send"
        )
    state.connected = True


MACHINE_LOGINS = frozenset({Login.PLCDEBUG.value, Login.DNC.value})
"""Logins that open machine-changing commands (PLC writes, machine control): safe mode refuses
them when asked for explicitly. Read operations still take them internally through
:func:`ensure_login`, because controls demand them for R_MB (PLCDEBUG) and R_RI (DNC)."""


def login(state: SessionState, name: Login | str, password: str | None = None) -> Op[None]:
    """Log in explicitly (no-op if already held).

    In safe mode an explicit PLCDEBUG or DNC login raises :class:`SafetyLockError` before
    anything is sent: holding one would let any later command change the machine.
    """
    if str(name).strip().upper() in MACHINE_LOGINS:
        require_unsafe(state, f"login {str(name).strip().upper()}")
    yield from ensure_login(state, name, password)


def logout(state: SessionState, name: Login | str | None = None) -> Op[None]:
    """Drop one login, or all logins when ``name`` is ``None``."""
    yield from command(Logout(None if name is None else str(name)), "logout")
    if name is None:
        state.logins.clear()
    else:
        state.logins.discard(str(name))


@dataclass(frozen=True, slots=True)
class SystemInfo:
    """``R_CI`` answers; ``None`` where the control does not support the selector."""

    turbo_mode: bool | None
    dnc_allowed: bool | None
    axes_sampling_rate: int | None
    """Base sampling interval of the axes in µs."""


def system_info_all(state: SessionState) -> Op[SystemInfo]:
    """Turbo mode, DNC allowed and axes sampling rate."""
    turbo = yield from read_system_info(state, SystemInfoSelector.TURBO_MODE)
    dnc = yield from read_system_info(state, SystemInfoSelector.DNC_ALLOWED)
    rate = yield from read_system_info(state, SystemInfoSelector.AXES_SAMPLING_RATE)
    return SystemInfo(
        None if turbo is None else bool(turbo),
        None if dnc is None else bool(dnc),
        None if rate is None else int(rate),
    )
