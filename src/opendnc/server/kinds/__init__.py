"""Machine kinds: one package per kind (``kinds/<kind>/``: its configuration schema, its
connector, its capabilities and hooks), the generic parts every kind shares
(:mod:`.base`), and the one table of them (:mod:`.registry`).

This module imports nothing, so that importing :mod:`.base` (which generic server modules do)
never loads the kinds themselves (docs/server.md#shape-components-and-kinds). Besides the
kinds, the package holds what every connector shares: the connector interface
(:mod:`.connector`), the files on a control (:mod:`.files`) and the DPRNT tap (:mod:`.dprnt_tap`).

The package may import the core and the store, nothing above them.
"""
