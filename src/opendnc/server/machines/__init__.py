"""One connector per control kind behind one small interface (:class:`Connector`).

A connector knows its protocol and nothing of the database; the supervisor
(:mod:`opendnc.server.supervisor`) owns the loop, the queue and the events.
"""

from __future__ import annotations

from opendnc.server.config import MachineConfig, MachineKind
from opendnc.server.machines.base import Connector, MachineStatus, Progress, Reception

__all__ = ["Connector", "MachineStatus", "Progress", "Reception", "connector_for"]


def connector_for(config: MachineConfig) -> Connector:
    """The connector that reaches ``config``'s control."""
    if config.kind is MachineKind.LSV2:
        from opendnc.server.machines.lsv2 import Lsv2Connector

        return Lsv2Connector(config)
    if config.kind is MachineKind.HAAS_NGC:
        from opendnc.server.machines.haas_ngc import HaasNgcConnector

        return HaasNgcConnector(config)
    from opendnc.server.machines.haas_serial import HaasSerialConnector

    return HaasSerialConnector(config)
