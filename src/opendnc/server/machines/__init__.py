"""One connector per control kind behind one small interface (:class:`Connector`).

A connector knows its protocol and nothing of the database; the machine tasks
(:mod:`opendnc.server.fleet`) own the loop, the runner (:mod:`opendnc.server.runner`) the queue.
Which connector a machine gets is its kind module's business (:mod:`opendnc.server.kinds`).
"""

from __future__ import annotations

from opendnc.server.kinds import connector_for
from opendnc.server.machines.base import Connector, MachineStatus, Progress, Reception

__all__ = ["Connector", "MachineStatus", "Progress", "Reception", "connector_for"]
