"""The configuration schema of a Heidenhain control over LSV2 (its own module: the connector
reads it, and the kind's spec imports the connector)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from opendnc.server.kinds.base import MachineBase, SerialProfile

__all__ = ["LSV2_SERIAL", "Lsv2Machine"]

# LSV2 over RS-232 runs at 57600 baud 8E1 without flow control by default (the controls' own
# default).
LSV2_SERIAL = SerialProfile(baud=57600, parity="E", flow="none")


@dataclass(frozen=True, kw_only=True)
class Lsv2Machine(MachineBase):
    """A Heidenhain control reached over LSV2."""

    kind: ClassVar[str] = "lsv2"
    control_family: ClassVar[str | None] = "heidenhain"

    host: str = ""  # TCP
    port: int = 19000
    serial: str = ""  # or RS-232: a device or URL
    profile: SerialProfile = LSV2_SERIAL  # the line of an RS-232 link
    folder: str = ""  # where programs go on the control (default TNC:/nc_prog)
    receive_folder: str = ""  # a folder whose files come to the inbox (auto-receive)
    receive_pattern: str = "*"  # which files of receive_folder (a glob, any case)
    receive_every: int = 5  # status polls between two listings of receive_folder
    after_receive: str = "keep"  # keep or delete a received file on the control
