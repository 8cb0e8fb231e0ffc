"""What a machine can do, asked by the pages, the actions and the runner instead of its kind.

The shared contract of the server's shape (docs/server.md#shape-components-and-kinds): code
that needs to know whether a machine has a file browser or can drip-feed asks
:func:`capabilities_of`, never ``machine.kind``. Each machine kind's module
(``kinds/<kind>/``) declares its own values; this module is the stable place to ask.
"""

from __future__ import annotations

from opendnc.server.kinds.base import Capabilities
from opendnc.server.kinds.registry import capabilities_of

__all__ = ["Capabilities", "capabilities_of"]
