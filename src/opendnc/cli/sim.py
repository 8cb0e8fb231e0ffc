"""`opendnc sim` commands: virtual controls and the virtual null-modem cable.

Each simulator is imported only when it is run (see :mod:`opendnc.cli.main`).
"""

from __future__ import annotations

from opendnc.cli.lazy import Lazy, lazy_typer

app = lazy_typer(
    "Virtual controls and links for testing without a machine.",
    {
        "tnc": Lazy("opendnc.cli.sim_tnc:tnc", "Run a virtual Heidenhain TNC (LSV2 over TCP)."),
        "cable": Lazy("opendnc.cli.sim_cable:cable", "Run a virtual null-modem cable."),
        "haas": Lazy("opendnc.cli.sim_haas:haas", "Run a virtual Haas control."),
        "fanuc": Lazy("opendnc.cli.sim_fanuc:fanuc", "Run a virtual Fanuc on a serial port."),
        "opcua": Lazy("opendnc.cli.sim_opcua:opcua", "Run a virtual OPC UA (umati) server."),
        "ftp": Lazy("opendnc.cli.sim_ftp:ftp", "Serve a virtual control's FTP folder."),
        "fleet": Lazy("opendnc.cli.sim_fleet:fleet", "Run many virtual controls in one process."),
    },
)
