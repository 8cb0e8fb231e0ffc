"""A small Haas program runner: what DNC tools observe, not how metal is cut.

It executes macro assignments and arithmetic, ``IF``/``GOTO``/``WHILE``, ``DPRNT``,
``G65 P9995`` single-surface Z probing against a synthetic surface (updating the work
offset Z, e.g. ``#5223`` for ``W54.``, as WIPS does), ``T`` + ``M06`` tool changes, ``M30``
part counters and cycle times, positions (``G90``/``G91``/``G53``, ``G54``..``G59``,
``G154 P``, ``G28`` to machine zero). Motion is instantaneous; the block rate is the
driver's business.

Sans-IO: the runner takes an injected ``clock`` and reports what happens as typed events
through ``emit``. It reads blocks from a :class:`BlockSource`, which a DNC front-end may keep
appending to while the program runs (the runner then reports :attr:`StepResult.WAITING`).
Program faults become alarms (:class:`~opendnc.sim.haas.machine.Alarm`), as on a control.
"""

from __future__ import annotations

import enum
import math
import random
import re
from collections.abc import Callable
from dataclasses import dataclass

from opendnc.errors import InputError
from opendnc.gcode.program import (
    Assign,
    Block,
    Dprnt,
    EndLoop,
    Expr,
    Goto,
    IfGoto,
    IfThen,
    PortControl,
    While,
    Words,
    evaluate,
    parse_block,
    variable_number,
)
from opendnc.haas import dprnt, macros
from opendnc.sim.haas.machine import AXES, Alarm, MachineState, Mode, Status, work_offset_base

Clock = Callable[[], float]
Surface = Callable[[float, float], float]
"""Machine X, Y -> machine Z of the part surface there."""

# The simulator's own alarm numbers (real Haas numbers differ by control generation).
ALARM_PROGRAM = Alarm(1001, "PROGRAM ERROR")
ALARM_PROBE = Alarm(1086, "PROBE NOT TRIGGERED")
ALARM_PROBE_CYCLE = Alarm(1087, "PROBE CYCLE NOT SIMULATED")
ALARM_GOTO = Alarm(1002, "BLOCK NUMBER NOT FOUND")


class StepResult(enum.Enum):
    """What one :meth:`ProgramRunner.step` did."""

    RAN = "ran"
    WAITING = "waiting"  # the source has no next block yet (DNC stream not finished)
    ENDED = "ended"  # M30/M02 or end of a complete source
    ALARM = "alarm"


@dataclass(frozen=True, slots=True)
class DprntLine:
    """A DPRNT block printed ``text`` (line end not included)."""

    text: str


@dataclass(frozen=True, slots=True)
class PortCode:
    """POPEN / PCLOS emitted a device-control byte (DC2 / DC4)."""

    code: bytes


@dataclass(frozen=True, slots=True)
class ToolChanged:
    """``M06`` loaded ``tool``; ``changes`` is the new total."""

    tool: int
    changes: int


@dataclass(frozen=True, slots=True)
class CycleEnded:
    """``M30`` ended a cycle of ``seconds``; ``parts`` is M30 counter #1 after it."""

    seconds: float
    parts: int


@dataclass(frozen=True, slots=True)
class AlarmRaised:
    """The run stopped on ``alarm``; ``detail`` says why."""

    alarm: Alarm
    detail: str


RunnerEvent = DprntLine | PortCode | ToolChanged | CycleEnded | AlarmRaised


class BlockSource:
    """Program lines: complete (a stored program) or growing (a DNC stream)."""

    def __init__(self, lines: list[str] | None = None, *, complete: bool = True) -> None:
        self._lines = list(lines or [])
        self._blocks: dict[int, Block] = {}
        self.complete = complete

    def append(self, line: str) -> None:
        """Add a line received while streaming."""
        self._lines.append(line)

    def close(self) -> None:
        """No more lines will come."""
        self.complete = True

    def __len__(self) -> int:
        return len(self._lines)

    def block(self, index: int) -> Block:
        """Parsed block ``index`` (parsed once, on first use)."""
        if index not in self._blocks:
            self._blocks[index] = parse_block(self._lines[index])
        return self._blocks[index]


@dataclass
class CycleTimes:
    """Cycle bookkeeping the MDC time queries report."""

    last: float = 0.0
    previous: float = 0.0
    cutting_total: float = 0.0


class ProgramRunner:
    """Run one program on ``machine``; call :meth:`step` until it stops returning RAN."""

    def __init__(
        self,
        source: BlockSource,
        machine: MachineState,
        *,
        clock: Clock,
        emit: Callable[[RunnerEvent], None],
        surface: Surface | None = None,
        times: CycleTimes | None = None,
        name: str = "O00000",
        mode: Mode = Mode.MEM,
        strict_probe: bool = False,
        probe_noise_um: float = 0.0,
        rng: random.Random | None = None,
    ) -> None:
        self.source = source
        self.machine = machine
        self.clock = clock
        self.emit = emit
        self.surface = surface
        self.times = times or CycleTimes()
        self.name = name
        self.strict_probe = strict_probe
        # probe repeatability: one standard deviation in micrometres, converted to the
        # program's units (G20 inch / G21 mm) at each touch
        self.probe_noise_um = probe_noise_um
        self.rng = rng or random.Random()
        self.metric = False
        self.index = 0
        self.blocks_run = 0
        self.probe_on = False
        self.cycle_start = clock()
        self.finished = False
        machine.mode = mode
        machine.status = Status.BUSY
        machine.program = name

    def elapsed(self) -> float:
        """Seconds since this cycle started."""
        return max(0.0, self.clock() - self.cycle_start)

    def run(self, max_blocks: int = 1_000_000) -> StepResult:
        """Step until the program ends, waits for input or alarms (or ``max_blocks``)."""
        result = StepResult.RAN
        for _ in range(max_blocks):
            result = self.step()
            if result is not StepResult.RAN:
                break
        return result

    def step(self) -> StepResult:
        """Execute the next block."""
        if self.finished:
            return StepResult.ENDED
        if self.index >= len(self.source):
            if not self.source.complete:
                return StepResult.WAITING
            return self._end(count_part=False)
        try:
            block = self.source.block(self.index)
            self.index += 1
            result = self._execute(block)
        except InputError as exc:
            return self._alarm(ALARM_PROGRAM, str(exc))
        if result is StepResult.RAN:
            self.blocks_run += 1
        return result

    def abort(self, alarm: Alarm, detail: str) -> None:
        """Stop the run on ``alarm`` (reset, lost DNC link...)."""
        if not self.finished:
            self._alarm(alarm, detail)

    # --------------------------------------------------------------- internals
    def _alarm(self, alarm: Alarm, detail: str) -> StepResult:
        self.finished = True
        self.times.cutting_total += self.elapsed()
        self.machine.alarms.append(alarm)
        self.machine.status = Status.ALARM
        self.emit(AlarmRaised(alarm, detail))
        return StepResult.ALARM

    def _end(self, *, count_part: bool) -> StepResult:
        self.finished = True
        seconds = self.elapsed()
        self.times.cutting_total += seconds
        if count_part:
            self.times.previous, self.times.last = self.times.last, seconds
            self.machine.m30_counter_1 += 1
            self.machine.m30_counter_2 += 1
            self.emit(CycleEnded(seconds, self.machine.m30_counter_1))
        self.machine.status = Status.IDLE
        return StepResult.ENDED

    def _value(self, expr: Expr) -> float:
        value = evaluate(expr, self.machine.get)
        return 0.0 if value is None else value

    def _jump_to(self, number: float) -> StepResult:
        target = round(number)
        for index in range(len(self.source)):
            if self.source.block(index).number == target:
                self.index = index
                return StepResult.RAN
        if not self.source.complete:
            self.index -= 1  # retry this GOTO once more of the stream has arrived
            return StepResult.WAITING
        return self._alarm(ALARM_GOTO, f"GOTO {target}: no block N{target}")

    def _execute(self, block: Block) -> StepResult:
        statement = block.statement
        if block.deleted:
            return StepResult.RAN
        if isinstance(statement, Assign):
            return self._assign(statement, block)
        elif isinstance(statement, IfThen):
            if self._value(statement.condition):
                return self._assign(statement.then, block)
        elif isinstance(statement, IfGoto):
            if self._value(statement.condition):
                return self._jump_to(self._value(statement.target))
        elif isinstance(statement, Goto):
            return self._jump_to(self._value(statement.target))
        elif isinstance(statement, While):
            if not self._value(statement.condition):
                return self._skip_loop(statement.loop)
        elif isinstance(statement, EndLoop):
            return self._loop_back(statement.loop)
        elif isinstance(statement, Dprnt):
            self.emit(DprntLine(dprnt.render(statement.items, self.machine.get)))
        elif isinstance(statement, PortControl):
            self.emit(PortCode(b"\x12" if statement.open else b"\x14"))
        else:
            return self._words(statement)
        return StepResult.RAN

    def _assign(self, statement: Assign, block: Block) -> StepResult:
        number = variable_number(statement.target, self.machine.get)
        value = evaluate(statement.value, self.machine.get)
        if number == macros.ALARM_VARIABLE:
            # #3000 = n (TEXT): alarm 1000 + n with the block's comment (docs/haas-macros.md)
            code = macros.alarm_for(value)
            comment = re.search(r"\(([^)]*)\)", block.source)
            text = comment.group(1).strip() if comment else "PROGRAMMABLE ALARM"
            return self._alarm(Alarm(code, text), f"#3000 = {code - macros.ALARM_BASE}")
        self.machine.set(number, value)
        return StepResult.RAN

    def _skip_loop(self, loop: int) -> StepResult:
        depth = 0
        for index in range(self.index, len(self.source)):
            statement = self.source.block(index).statement
            if isinstance(statement, While) and statement.loop == loop:
                depth += 1
            elif isinstance(statement, EndLoop) and statement.loop == loop:
                if depth == 0:
                    self.index = index + 1
                    return StepResult.RAN
                depth -= 1
        if not self.source.complete:
            self.index -= 1
            return StepResult.WAITING
        return self._alarm(ALARM_PROGRAM, f"WHILE ... DO{loop} without END{loop}")

    def _loop_back(self, loop: int) -> StepResult:
        depth = 0
        for index in range(self.index - 2, -1, -1):
            statement = self.source.block(index).statement
            if isinstance(statement, EndLoop) and statement.loop == loop:
                depth += 1
            elif isinstance(statement, While) and statement.loop == loop:
                if depth == 0:
                    self.index = index
                    return StepResult.RAN
                depth -= 1
        return self._alarm(ALARM_PROGRAM, f"END{loop} without WHILE ... DO{loop}")

    def _words(self, statement: Words) -> StepResult:
        machine = self.machine
        single: dict[str, float] = {}
        for letter, expr in statement.words:
            if letter not in "GM":
                single[letter] = self._value(expr)
        g_codes = [self._value(e) for e in statement.values("G")]
        m_codes = [round(self._value(e)) for e in statement.values("M")]
        if 65 in g_codes:
            return self._macro_call(single)
        machine_coords = False
        home = False
        for code in g_codes:
            if code in (20, 21):
                self.metric = code == 21
            elif code in (90, 91):
                machine.absolute = code == 90
            elif code == 53:
                machine_coords = True
            elif code == 28:
                home = True
            elif code == 154:
                machine.work_offset = 109 + round(single.get("P", 1))
            elif 54 <= code <= 59 and code == int(code):
                machine.work_offset = code
        self._move(single, machine_coords)
        if home:
            # G28: through the given point (above), then the named axes (all if none) home
            named = [axis for axis, letter in enumerate(AXES[:3]) if letter in single]
            for axis in named or [0, 1, 2]:
                machine.machine_position[axis] = 0.0
        if "S" in single:
            machine.spindle_rpm = single["S"]
        if "T" in single:
            machine.next_tool = round(single["T"])
        for code in m_codes:
            if code == 6:
                machine.tool = machine.next_tool
                machine.tool_changes += 1
                self.emit(ToolChanged(machine.tool, machine.tool_changes))
            elif code == 5:
                machine.spindle_rpm = 0.0
            elif code == 30:
                return self._end(count_part=True)
            elif code == 2:
                return self._end(count_part=False)
            elif code == 99:
                self.index = 0
            elif code in (97, 98):
                return self._alarm(ALARM_PROGRAM, f"M{code} subprograms are not simulated")
        return StepResult.RAN

    def _move(self, single: dict[str, float], machine_coords: bool) -> None:
        machine = self.machine
        machine.previous_end = [machine.work_position(i) for i in range(3)]
        for axis, letter in enumerate(AXES):
            if letter not in single:
                continue
            value = single[letter]
            if machine_coords:
                machine.machine_position[axis] = value
            elif machine.absolute:
                machine.machine_position[axis] = value + machine.offset(axis)
            else:
                machine.machine_position[axis] += value

    def _macro_call(self, args: dict[str, float]) -> StepResult:
        program = round(args.get("P", -1))
        if program == 9832:
            self.probe_on = True
        elif program == 9833:
            self.probe_on = False
        elif program == 9810:  # protected positioning move
            self._move({k: v for k, v in args.items() if k in AXES}, machine_coords=False)
        elif program == 9995 and round(args.get("A", -1)) == 20 and "H" in args:
            return self._probe_z(args)
        elif program == 9995:
            return self._alarm(ALARM_PROBE_CYCLE, "only G65 P9995 A20. with H is simulated")
        else:
            return self._alarm(ALARM_PROGRAM, f"macro program O{program:05d} not found")
        return StepResult.RAN

    def _probe_z(self, args: dict[str, float]) -> StepResult:
        machine = self.machine
        if self.surface is None:
            return self._alarm(ALARM_PROBE, "no surface to probe (simulator needs --surface)")
        x, y, z = machine.machine_position[:3]
        surface_z = self.surface(x, y)
        if math.isnan(surface_z):  # off a height map: nothing under the stylus
            return self._alarm(ALARM_PROBE, f"no surface under X{x:g} Y{y:g}")
        if self.probe_noise_um > 0:
            sigma = self.probe_noise_um / (1000.0 if self.metric else 25400.0)
            surface_z += self.rng.gauss(0.0, sigma)
        if self.strict_probe:
            reach = args["H"]
            low, high = sorted((z, z + reach))
            if not self.probe_on or not low <= surface_z <= high:
                return self._alarm(ALARM_PROBE, f"no surface within H{reach:g} of Z{z:g}")
        machine.skip_position = [
            x - machine.offset(0),
            y - machine.offset(1),
            surface_z - machine.offset(2),
        ]
        if "W" in args:
            base = work_offset_base(args["W"])
            machine.variables[base + 2] = surface_z
        # WIPS retracts to where the cycle started; the position does not change.
        return StepResult.RAN
