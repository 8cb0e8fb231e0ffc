"""A scripted machine behind the virtual agent: the values a control's adapter would send
as an operator starts a program, it cuts, holds, alarms, is reset and counts a part.

Tests call the steps one by one and check what the DNC server shows after each; the fleet
(:func:`run_cycles`) loops a whole cycle so a demo floor has machines that do something.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass

from opendnc.sim.mtconnect.agent import VirtualAgent

__all__ = ["ScriptedMachine", "run_cycles"]


@dataclass
class ScriptedMachine:
    """Device ``device`` of ``agent``, moved step by step."""

    agent: VirtualAgent
    device: str
    parts: int = 0
    line: int = 0

    def _set(self, item_type: str, value: str | int) -> None:
        self.agent.set(self.device, item_type, value)

    def power_on(self, *, parts: int = 0) -> None:
        """Available, E-stop armed, automatic, ready, no alarm, ``parts`` counted so far."""
        self.parts = parts
        self._set("AVAILABILITY", "AVAILABLE")
        self._set("EMERGENCY_STOP", "ARMED")
        self._set("CONTROLLER_MODE", "AUTOMATIC")
        self._set("EXECUTION", "READY")
        self._set("PART_COUNT", parts)
        self._set("PROGRAM", "")
        self._set("LINE_NUMBER", 0)
        self.agent.clear_faults(self.device)

    def power_off(self) -> None:
        """The control is switched off: the adapter reports it unavailable."""
        self._set("AVAILABILITY", "UNAVAILABLE")

    def start(self, program: str) -> None:
        """Cycle start of ``program``."""
        self.line = 1
        self._set("PROGRAM", program)
        self._set("LINE_NUMBER", self.line)
        self._set("EXECUTION", "ACTIVE")

    def cut(self, lines: int = 10) -> None:
        """The program runs on by ``lines`` blocks."""
        self.line += lines
        self._set("LINE_NUMBER", self.line)

    def feed_hold(self) -> None:
        """The operator holds the feed."""
        self._set("EXECUTION", "FEED_HOLD")

    def resume(self) -> None:
        """Cycle start again after a hold."""
        self._set("EXECUTION", "ACTIVE")

    def alarm(self, code: str, text: str) -> None:
        """The control raises alarm ``code`` and stops."""
        self.agent.fault(self.device, code, text)
        self._set("EXECUTION", "STOPPED")

    def emergency_stop(self) -> None:
        """The E-stop button is pressed."""
        self._set("EMERGENCY_STOP", "TRIGGERED")
        self._set("EXECUTION", "STOPPED")

    def reset(self) -> None:
        """Reset: alarms clear, E-stop released, the control is ready."""
        self.agent.clear_faults(self.device)
        self._set("EMERGENCY_STOP", "ARMED")
        self._set("EXECUTION", "READY")

    def finish(self) -> None:
        """M30: the program completes and the part is counted."""
        self.parts += 1
        self._set("PART_COUNT", self.parts)
        self._set("EXECUTION", "PROGRAM_COMPLETED")


async def run_cycles(machine: ScriptedMachine, cycle: float, *, program: str = "O1000") -> None:
    """Run ``program`` over and over, one part every ``cycle`` seconds, a feed hold every
    fifth part and an alarm every thirteenth; runs until cancelled."""
    machine.power_on()
    step = cycle / 10
    part = 0
    while True:
        part += 1
        machine.start(program)
        for _ in range(6):
            await asyncio.sleep(step)
            machine.cut()
        if part % 5 == 0:
            machine.feed_hold()
            await asyncio.sleep(step)
            machine.resume()
        if part % 13 == 0:
            machine.alarm("1010", "SPINDLE OVERLOAD")
            await asyncio.sleep(step)
            machine.reset()
            continue
        await asyncio.sleep(step)
        machine.finish()
        await asyncio.sleep(step)
