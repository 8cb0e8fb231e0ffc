"""Machine actions: the configured machines and their live state."""

from __future__ import annotations

from opendnc.server.actions.base import Caller, Services, require
from opendnc.server.actions.models import MachineOut
from opendnc.server.store.models import Role

__all__ = ["get_machine", "list_machines"]


def list_machines(svc: Services, who: Caller) -> list[MachineOut]:
    """Every configured machine with its live state."""
    require(who, Role.VIEWER)
    return [MachineOut.model_validate(m.as_json()) for m in svc.runner.machines.values()]


def get_machine(svc: Services, who: Caller, name: str) -> MachineOut:
    """One machine with its live state."""
    require(who, Role.VIEWER)
    return MachineOut.model_validate(svc.machine(name).as_json())
