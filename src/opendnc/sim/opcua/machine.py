"""A scripted machine tool behind the virtual OPC UA server: the values a control's server
would show as an operator starts a program, it cuts, holds, alarms, is reset and counts a part.

Tests call the steps one by one and check what the DNC server shows after each; the fleet
(:func:`run_cycles`) loops a whole cycle so a demo floor has machines that do something.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass
from typing import Any

from asyncua import ua
from asyncua.common.node import Node

from opendnc.opcua.model import ChannelMode, ChannelState, ProgramState, SignalColor
from opendnc.sim.opcua.server import MachineNodes

__all__ = ["ScriptedMachineTool", "run_cycles"]

ALARM_SEVERITY = 800  # an alert's Severity (1..1000); ours, a fault that stops the machine


@dataclass
class ScriptedMachineTool:
    """One machine of a :class:`~opendnc.sim.opcua.server.VirtualOpcuaServer`, step by step."""

    nodes: MachineNodes
    parts: int = 0
    feed: float = 100.0

    async def _light(self, color: SignalColor) -> None:
        for each, node in self.nodes.lights.items():
            await node.write_value(each == color)

    async def power_on(self, *, parts: int = 0) -> None:
        """Automatic, channel reset, no program, no alarm, ``parts`` made so far."""
        self.parts = parts
        await _write(self.nodes.parts, parts, ua.VariantType.UInt64)
        await _write(self.nodes.channel_mode, int(ChannelMode.AUTOMATIC), ua.VariantType.Int32)
        await _write(self.nodes.channel_state, int(ChannelState.RESET), ua.VariantType.Int32)
        await self.nodes.program.write_value("")
        await self.nodes.program_state.write_value(ua.LocalizedText(ProgramState.INITIALIZING))
        await self._clear_alarms()
        await self._light(SignalColor.OFF)

    async def start(self, program: str, number: int = 1) -> None:
        """Cycle start of ``program`` (``number``: its place in the program list)."""
        await self.nodes.program.write_value(program)
        await _write(self.nodes.program_number, number, ua.VariantType.UInt16)
        await self.nodes.program_state.write_value(ua.LocalizedText(ProgramState.RUNNING))
        await _write(self.nodes.channel_state, int(ChannelState.ACTIVE), ua.VariantType.Int32)
        await self._light(SignalColor.GREEN)

    async def cut(self, feed: float = 90.0) -> None:
        """The program runs on; the operator turns the feed override to ``feed`` percent."""
        self.feed = feed
        await self.nodes.feed_override.write_value(float(feed))

    async def feed_hold(self) -> None:
        """The operator holds the feed: the channel and the program are interrupted."""
        await _write(self.nodes.channel_state, int(ChannelState.INTERRUPTED), ua.VariantType.Int32)
        await self.nodes.program_state.write_value(ua.LocalizedText(ProgramState.INTERRUPTED))
        await self._light(SignalColor.YELLOW)

    async def resume(self) -> None:
        """Cycle start again after a hold."""
        await self.nodes.program_state.write_value(ua.LocalizedText(ProgramState.RUNNING))
        await _write(self.nodes.channel_state, int(ChannelState.ACTIVE), ua.VariantType.Int32)
        await self._light(SignalColor.GREEN)

    async def alarm(self, code: str, text: str) -> None:
        """The control raises alert ``code`` and stops: the program is aborted."""
        await _write(self.nodes.channel_state, int(ChannelState.INTERRUPTED), ua.VariantType.Int32)
        await self.nodes.program_state.write_value(ua.LocalizedText(ProgramState.ABORTED))
        await self._light(SignalColor.RED)
        self.nodes.active_alarms[code] = text
        await _alert(self.nodes.alert, code, text, active=True)

    async def reset(self) -> None:
        """Reset: every alert goes inactive, the channel is reset."""
        await self._clear_alarms()
        await _write(self.nodes.channel_state, int(ChannelState.RESET), ua.VariantType.Int32)
        await self._light(SignalColor.OFF)

    async def finish(self) -> None:
        """M30: the program ends, the channel resets and the part is counted."""
        self.parts += 1
        await _write(self.nodes.parts, self.parts, ua.VariantType.UInt64)
        await self.nodes.program_state.write_value(ua.LocalizedText(ProgramState.ENDED))
        await _write(self.nodes.channel_state, int(ChannelState.RESET), ua.VariantType.Int32)
        await self._light(SignalColor.OFF)

    async def _clear_alarms(self) -> None:
        active, self.nodes.active_alarms = self.nodes.active_alarms, {}
        for code, text in active.items():
            await _alert(self.nodes.alert, code, text, active=False)


async def _write(node: Node, value: int, variant: ua.VariantType) -> None:
    await node.write_value(ua.Variant(value, variant))


async def _alert(generator: Any, code: str, text: str, *, active: bool) -> None:
    event = generator.event
    event.Message = ua.LocalizedText(text)
    event.Severity = ALARM_SEVERITY
    event.ErrorCode = code
    setattr(event, "ActiveState/Id", active)
    event.ActiveState = ua.LocalizedText("Active" if active else "Inactive")
    await generator.trigger()


async def run_cycles(machine: ScriptedMachineTool, cycle: float, *, program: str = "O1000") -> None:
    """Run ``program`` over and over, one part every ``cycle`` seconds, a feed hold every
    fifth part and an alarm every thirteenth; runs until cancelled."""
    await machine.power_on()
    step = cycle / 10
    part = 0
    while True:
        part += 1
        await machine.start(program)
        for i in range(6):
            await asyncio.sleep(step)
            await machine.cut(100.0 - 5 * (i % 3))
        if part % 5 == 0:
            await machine.feed_hold()
            await asyncio.sleep(step)
            await machine.resume()
        if part % 13 == 0:
            await machine.alarm("1010", "SPINDLE OVERLOAD")
            await asyncio.sleep(step)
            await machine.reset()
            continue
        await asyncio.sleep(step)
        await machine.finish()
        await asyncio.sleep(step)
