"""The ``mtconnect`` machine kind.

``schema.py`` holds its configuration, ``connector.py`` its link to the control, ``spec.py``
its parser, capabilities, hooks and ``SPEC`` (listed in :mod:`opendnc.server.kinds.registry`).
This module names only the schema, so the connector imports it without loading the spec.
"""

from __future__ import annotations

from opendnc.server.kinds.mtconnect.schema import MtconnectMachine

__all__ = ["MtconnectMachine"]
