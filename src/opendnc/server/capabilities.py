"""What a machine can do, asked by the pages, the actions and the runner instead of its kind.

The shared contract of the server's shape (docs/server.md#machines-and-connections): code that
needs to know whether a machine has a file browser or can drip-feed asks
:func:`capabilities_of`, never ``machine.kind``. Each machine kind's module declares its own
values; this module only holds the record and the lookup.
"""

from __future__ import annotations

from dataclasses import dataclass

from opendnc.server.config import MachineConfig, MachineKind

__all__ = ["Capabilities", "capabilities_of"]


@dataclass(frozen=True)
class Capabilities:
    """What the server can do with one machine."""

    file_browser: bool = False  # list, upload and delete files on the control (as jobs)
    dripfeed: bool = False  # run a program while it arrives (also needs the config's opt-in)
    dprnt: bool = False  # capture lines the program prints
    receive: bool = False  # the control sends programs by itself (punch or out-tray folder)
    status_fields: frozenset[str] = frozenset()  # which MachineStatus fields the control reports


_LSV2_STATUS = frozenset({"execution", "mode", "program", "line", "tool", "overrides", "errors"})
_NGC_STATUS = frozenset({"execution", "mode", "native_mode", "program", "part_count", "tool"})
_SERIAL_MDC_STATUS = frozenset({"execution", "mode", "native_mode", "program", "part_count"})


def capabilities_of(machine: MachineConfig) -> Capabilities:
    """The capabilities of ``machine`` as configured (its kind and its opt-ins)."""
    if machine.kind is MachineKind.LSV2:
        return Capabilities(
            file_browser=True,  # over the machine's own LSV2 session, TCP or RS-232 alike
            receive=bool(machine.receive_folder),
            status_fields=_LSV2_STATUS,
        )
    if machine.kind is MachineKind.HAAS_NGC:
        return Capabilities(dprnt=bool(machine.dprnt), status_fields=_NGC_STATUS)
    return Capabilities(
        dripfeed=machine.dripfeed,
        dprnt=bool(machine.dprnt),
        receive=True,  # a serial Haas punches programs to the listening port
        status_fields=_SERIAL_MDC_STATUS if machine.mdc else frozenset(),
    )
