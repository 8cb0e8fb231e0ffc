"""The shared state of one virtual control: profile, file system, PLC, machine, parameters.

All sessions (TCP connections) of a simulator share one :class:`Control`, as all clients of a
real control share its disk and machine.  Per-connection state lives in
:mod:`opendnc.sim.tnc.session`.
"""

from __future__ import annotations

import json
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

from opendnc.errors import ControlRefused
from opendnc.lsv2.constants import ErrorCode as E
from opendnc.sim.tnc import oplog
from opendnc.sim.tnc.filesystem import ControlFs, WirePath
from opendnc.sim.tnc.machine import Machine
from opendnc.sim.tnc.plc import MachineParameters, PlcMemory, table_rows
from opendnc.sim.tnc.population import populate
from opendnc.sim.tnc.profiles import Profile


class Control:
    """One virtual TNC shared by every connection of a simulator."""

    def __init__(
        self,
        profile: Profile,
        root: Path,
        *,
        clock: Callable[[], float] = time.monotonic,
        dnc_option: bool = True,
    ) -> None:
        self.profile = profile
        self.root = root
        self.dnc_option = dnc_option
        # The logbook keeps the most recent entries, as a control's ring buffer does.
        self.events: deque[tuple[float, str]] = deque(maxlen=5000)
        self.events.append((time.time(), "Control started"))
        self.fs = ControlFs(root, profile)
        populate(self.fs, profile)
        self.plc = PlcMemory(profile.plc)
        self.mp = MachineParameters(self.fs.state_dir, profile)
        self.machine = Machine(
            profile,
            self.plc,
            clock,
            tool_geometry=self.tool_geometry,
            tool_known=lambda n: n in self.tool_rows(),
            notify=self.log_event,
        )
        self.monitor_owner: int | None = None
        self.remote_status = bytes(12)
        self.on_received: Callable[[str, Path], None] | None = None
        """Called with the control's path and the host file of every completed upload (a
        fleet's receipts: how often each control received what)."""
        self._load_state()

    # -- persistence ------------------------------------------------------------------------
    def _load_state(self) -> None:
        """Restore what a real control keeps over a restart (retentive PLC, counters)."""
        state_dir = self.fs.state_dir
        image = state_dir / "plc.bin"
        if image.exists():
            raw = image.read_bytes()
            if len(raw) == len(self.plc.image):
                self.plc.image[:] = raw
        counters = state_dir / "machine.json"
        try:
            data = json.loads(counters.read_text("utf-8")) if counters.exists() else {}
        except (OSError, ValueError):
            data = {}
        m = self.machine
        if isinstance(data, dict):
            m.part_counter = int(data.get("part_counter", 0))
            m.tool = int(data.get("tool", 0))
            m.run_seconds = float(data.get("run_seconds", 0.0))
            m.spindle_seconds = float(data.get("spindle_seconds", 0.0))
            positions = data.get("positions", {})
            if isinstance(positions, dict):
                for axis, value in positions.items():
                    if axis in m.positions:
                        m.positions[axis] = float(value)
        m.advance()

    def save_state(self) -> None:
        """Write PLC image and machine counters to the root's state folder (atomically)."""
        m = self.machine
        m.advance()
        data = {
            "part_counter": m.part_counter,
            "tool": m.tool,
            "run_seconds": m.run_seconds,
            "spindle_seconds": m.spindle_seconds,
            "positions": m.positions,
        }
        for name, blob in (
            ("plc.bin", bytes(self.plc.image)),
            ("machine.json", json.dumps(data, indent=1).encode()),
        ):
            target = self.fs.state_dir / name
            tmp = target.with_suffix(".tmp")
            tmp.write_bytes(blob)
            tmp.replace(target)

    # -- tool table -------------------------------------------------------------------------
    def tool_rows(self) -> dict[int, dict[str, str]]:
        """Rows of the tool table keyed by tool number (empty when missing or unreadable)."""
        wp = self.fs.parse(self.profile.paths.tool_table, WirePath("TNC:", ()))
        try:
            text = self.fs.read_bytes(wp).decode("latin-1")
        except ControlRefused:
            return {}
        rows: dict[int, dict[str, str]] = {}
        for row in table_rows(text):
            try:
                rows[int(row.get("T", ""))] = row
            except ValueError:
                continue
        return rows

    def tool_geometry(self, number: int) -> tuple[float, float]:
        """(L, R) of a tool from the table, zeros when unknown."""
        row = self.tool_rows().get(number, {})
        try:
            return float(row.get("L", 0) or 0), float(row.get("R", 0) or 0)
        except ValueError:
            return 0.0, 0.0

    # -- logbook ----------------------------------------------------------------------------
    def log_event(self, text: str) -> None:
        """Append an entry to the operations log."""
        self.events.append((time.time(), text))

    def write_operations_log(self, request: oplog.LogRequest, cwd: WirePath) -> WirePath:
        """Create the operations log file the client asked for (C_CC 27)."""
        wp = self.fs.parse(request.name, cwd)
        text = oplog.render(self.events, request.since, self.profile.model)
        self.fs.write_atomic(wp, text.encode("latin-1", "replace"))
        return wp

    # -- program selection ------------------------------------------------------------------
    def select_program(self, path: str | WirePath) -> None:
        """Select a program for execution (DNC ``C_NC`` or the API), e.g. ``TNC:\\a.h``."""
        wp = self.fs.parse(path, WirePath("TNC:", ())) if isinstance(path, str) else path
        canonical = self.fs.canonical(wp)
        suffixes = {e.lower() for e in self.profile.paths.program_ext}
        if "." + canonical.name.rsplit(".", 1)[-1].lower() not in suffixes:
            raise ControlRefused(
                E.T_ER_BAD_FILE, f"{canonical} is not an NC program of this control"
            )
        text = self.fs.read_bytes(canonical).decode("latin-1")
        self.machine.select(str(canonical), text)
        self.fs.set_selected([canonical])
        self.log_event(f"Program selected: {canonical}")
