"""The ``opcua`` machine kind: a machine tool read through its OPC UA server (OPC 40501-1).

``schema.py`` holds its configuration, ``connector.py`` its link to the control, ``spec.py``
its parser, capabilities and ``SPEC`` (listed in :mod:`opendnc.server.kinds.registry`).
This module names only the schema, so the connector imports it without loading the spec.
"""

from __future__ import annotations

from opendnc.server.kinds.opcua.schema import OpcuaMachine

__all__ = ["OpcuaMachine"]
