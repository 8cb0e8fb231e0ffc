"""One connector per control kind behind one small interface (:class:`Connector`).

A connector knows its protocol and nothing of the database; the machine tasks
(:mod:`opendnc.server.fleet`) own the loop, the runner (:mod:`opendnc.server.runner`) the queue.
Which connector a machine gets is its kind package's business (:mod:`opendnc.server.kinds`,
:func:`opendnc.server.kinds.registry.connector_for`).
"""

from __future__ import annotations

from opendnc.server.machines.base import Connector, MachineStatus, Progress, Reception

__all__ = ["Connector", "MachineStatus", "Progress", "Reception"]
