"""Machine state of the virtual TNC, advanced lazily from an injected clock.

No timers and no I/O: every query calls :meth:`Machine.advance` with the clock's current
time, so tests drive the machine with a fake clock and the server with ``time.monotonic``.
A selected program runs block by block (``block_time`` seconds per NC block, scaled by the
feed override); axes interpolate towards each block's target, ``TOOL CALL``/``T`` changes
the tool, ``M3``/``M5`` switch the spindle, and the part counter counts finished runs.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field

from opendnc.errors import ControlRefused
from opendnc.lsv2.constants import ErrorCode as E
from opendnc.lsv2.constants import ExecutionMode, ProgramState
from opendnc.sim.tnc.plc import (
    D_PART_COUNTER,
    D_PROGRAM_STATE,
    D_SPINDLE_SPEED,
    D_TOOL_NUMBER,
    M_ERROR_PENDING,
    M_PROGRAM_RUNNING,
    M_SPINDLE_ON,
    W_FEED_OVERRIDE,
    W_RAPID_OVERRIDE,
    W_SPINDLE_OVERRIDE,
    PlcMemory,
)
from opendnc.sim.tnc.profiles import KeyStyle, Profile

# The simulator answers with the codec's own enums, so both sides share one value table.
ExecMode = ExecutionMode
PgmState = ProgramState


OPERATING_MODE = E.T_ER_OPERATING_MODE
BAD_EMULATEKEY = E.T_ER_BAD_EMULATEKEY
NC_START_KEY = 0x00F0  # NC start as a hobby project sent it (docs/lsv2.md#keyboard) (guess)
NC_STOP_KEY = 0x00F1  # our own choice, next to NC start (guess)

NEW_MODE_KEYS = {0x01C0: 0, 0x01C1: 1, 0x01C2: 3, 0x01C3: 4, 0x01C5: 0}
OLD_MODE_KEYS = {0x0048: 0, 0x0040: 0, 0x004A: 3, 0x0049: 1, 0x004B: 4}
NEW_SCREEN_KEYS = {0x01C4: "Programming", 0x01C6: "Test run", 0x01C7: "MOD", 0x01CB: "PGM MGT"}
OLD_SCREEN_KEYS = {0x004C: "Programming", 0x0041: "Test run", 0x0042: "MOD", 0x0061: "PGM MGT"}
MODE_NAMES = {
    0: "Manual operation",
    1: "Positioning w/ manual data input",
    2: "Reference run",
    3: "Program run, single block",
    4: "Program run, full sequence",
}


def _valid_new_key(code: int) -> bool:
    return (
        0x0008 <= code <= 0x007A
        or 0x0150 <= code <= 0x0189
        or code in (0x019D, 0x019E)
        or 0x01A0 <= code <= 0x01EF
        or code in (NC_START_KEY, NC_STOP_KEY)
    )


def _valid_old_key(code: int) -> bool:
    low = code & 0xFF
    return low in (0x50, 0x51, 0x52) or 0x003A <= code <= 0x007F or code in (0x00FF, 0x00F0, 0x00F1)


@dataclass(frozen=True, slots=True)
class Block:
    """One NC block as the run simulation needs it."""

    number: int
    targets: dict[str, float]
    tool: int | None
    speed: int | None
    spindle_on: bool | None
    call: str | None = None  # CALL PGM target: the program stack's current program


@dataclass(slots=True)
class NcError:
    """An entry of the NC error list (``R_RI`` 27/28, docs/lsv2.md#nc-errors)."""

    error_class: int
    group: int
    number: int
    text: str


_AXIS_RE = re.compile(r"(?<![A-Z])([XYZABCUVW])\s*([+-]?\d+(?:\.\d*)?)", re.IGNORECASE)
_TOOL_RE = re.compile(r"TOOL CALL\s+(\d+)|(?<![A-Z])T(\d+)(?!\w)", re.IGNORECASE)
_SPEED_RE = re.compile(r"(?<![A-Z])S(\d+)", re.IGNORECASE)
_M_RE = re.compile(r"(?<![A-Z])M0?(\d+)", re.IGNORECASE)
_CALL_RE = re.compile(r"(?:CALL PGM|PGM CALL)\s+(\S+)", re.IGNORECASE)
_SKIP_RE = re.compile(r"BLK FORM|G3[01]\b|BEGIN PGM|END PGM|^\s*%", re.IGNORECASE)


def parse_program(text: str) -> list[Block]:
    """NC blocks of a Klartext, ISO or lathe program, with their movement targets."""
    blocks = []
    for number, raw in enumerate(text.splitlines()):
        line = raw.split(";", 1)[0]
        if _SKIP_RE.search(line):
            blocks.append(Block(number, {}, None, None, None))
            continue
        body = re.sub(r"^\s*N?\d+\s", " ", line)  # drop the block number
        call = _CALL_RE.search(body)
        if call:
            blocks.append(Block(number, {}, None, None, None, call.group(1)))
            continue
        targets = {m.group(1).upper(): float(m.group(2)) for m in _AXIS_RE.finditer(body)}
        tool_m = _TOOL_RE.search(body)
        tool = int(tool_m.group(1) or tool_m.group(2)) if tool_m else None
        speed_m = _SPEED_RE.search(body)
        spindle: bool | None = None
        for m in _M_RE.finditer(body):
            code = int(m.group(1))
            if code in (3, 4, 13):
                spindle = True
            elif code in (5, 30, 2):
                spindle = False
        blocks.append(
            Block(number, targets, tool, int(speed_m.group(1)) if speed_m else None, spindle)
        )
    return blocks


@dataclass(slots=True)
class Run:
    """Bookkeeping of the running program."""

    blocks: list[Block]
    elapsed: float = 0.0  # run seconds (feed-scaled) consumed before ``resumed_at``
    resumed_at: float | None = None
    stop_at: float | None = None  # single-block mode: where this NC start ends
    checked: int = 0  # blocks up to here were checked (tool known ...)


@dataclass(slots=True)
class Machine:
    """The shared machine state of one virtual control."""

    profile: Profile
    plc: PlcMemory
    clock: Callable[[], float]
    tool_geometry: Callable[[int], tuple[float, float]] = lambda _n: (0.0, 0.0)
    tool_known: Callable[[int], bool] = lambda _n: True
    notify: Callable[[str], None] = lambda _text: None  # operations-log entries
    block_time: float = 0.25
    exec_mode: ExecMode = ExecMode.MANUAL
    program_state: PgmState = PgmState.IDLE
    screen: str = "Manual operation"
    main_program: str = ""
    current_program: str = ""
    current_line: int = 0
    part_counter: int = 0
    feed_override: int = 10000
    spindle_override: int = 10000
    rapid_override: int = 10000
    spindle_speed: int = 0
    spindle_on: bool = False
    tool: int = 0
    positions: dict[str, float] = field(default_factory=dict)
    errors: list[NcError] = field(default_factory=list)
    keyboard_locked: bool = False
    booted_at: float = 0.0
    run_seconds: float = 0.0
    spindle_seconds: float = 0.0
    _program_text: str = ""
    _run: Run | None = None
    _last: float = 0.0
    _start_pos: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        now = self.clock()
        self.booted_at = self._last = now
        axes = ("X", "Z") if self.profile.lathe else ("X", "Y", "Z", "B", "C")
        home = {"X": 0.0, "Y": 0.0, "Z": 250.0, "B": 0.0, "C": 0.0}
        self.positions = {a: home[a] for a in axes}
        self.errors.append(NcError(3, 3, -2130706422, "010 Relay external DC voltage missing"))
        self._publish()

    # -- time -----------------------------------------------------------------------------
    def advance(self) -> None:
        """Bring the state up to the clock's current time."""
        now = self.clock()
        dt = max(0.0, now - self._last)
        self._last = now
        run = self._run
        if run is None or run.resumed_at is None:
            self._publish()
            return
        self.run_seconds += dt
        if self.spindle_on:
            self.spindle_seconds += dt
        scale = max(self.feed_override, 0) / 10000.0
        run.elapsed += dt * scale
        run.resumed_at = now
        if run.stop_at is not None and run.elapsed >= run.stop_at:
            # Single block: the block is done, the control waits for the next NC start.
            run.elapsed = run.stop_at
            run.resumed_at = None
            run.stop_at = None
            self.program_state = PgmState.STOPPED
        self._apply_progress(run)
        self._publish()

    def _apply_progress(self, run: Run) -> None:
        position = run.elapsed / self.block_time
        index = int(position)
        if not self._check_blocks(run, min(index, len(run.blocks) - 1)):
            return
        if index >= len(run.blocks):
            for block in run.blocks:
                self._apply_block(block)
            self.current_line = len(run.blocks) - 1 if run.blocks else 0
            self.current_program = self.main_program
            self.program_state = PgmState.FINISHED
            self.part_counter += 1
            self.notify(f"Program finished: {self.main_program} (parts {self.part_counter})")
            self.spindle_on = False
            self._run = None
            return
        # Re-derive everything up to the current block (runs are short; keeps it exact).
        self.positions.update(self._start_pos)
        for block in run.blocks[:index]:
            self._apply_block(block)
        block = run.blocks[index]
        frac = position - index
        for axis, target in block.targets.items():
            if axis in self.positions:
                start = self.positions[axis]
                self.positions[axis] = start + (target - start) * frac
        if block.tool is not None:
            self.tool = block.tool
        self.current_line = block.number
        self.current_program = self._called(block.call) if block.call else self.main_program

    def _called(self, name: str) -> str:
        """Path of a called program: absolute, or relative to the main program's folder."""
        name = name.replace("/", "\\")
        if ":" in name:
            return name
        folder = self.main_program.rsplit("\\", 1)[0]
        return folder + "\\" + name

    def _check_blocks(self, run: Run, upto: int) -> bool:
        """Check blocks once when first reached; a TOOL CALL of an unknown tool is an error."""
        while run.checked <= upto:
            block = run.blocks[run.checked]
            if block.tool is not None and not self.tool_known(block.tool):
                self.positions.update(self._start_pos)
                for done in run.blocks[: run.checked]:
                    self._apply_block(done)
                self.current_line = block.number
                self.errors.append(NcError(3, 3, 0x0103, f"Tool {block.tool} not defined"))
                self.notify(f"NC error: Tool {block.tool} not defined")
                self.program_state = PgmState.ERROR
                self.spindle_on = False
                self._run = None
                return False
            run.checked += 1
        return True

    def _apply_block(self, block: Block) -> None:
        for axis, target in block.targets.items():
            if axis in self.positions:
                self.positions[axis] = target
        if block.tool is not None:
            self.tool = block.tool
        if block.speed is not None:
            self.spindle_speed = block.speed
        if block.spindle_on is not None:
            self.spindle_on = block.spindle_on

    def _publish(self) -> None:
        """Mirror live values into the PLC image so R_MB and R_DP see them."""
        plc = self.plc
        plc.set_word(W_FEED_OVERRIDE, self.feed_override // 1)
        plc.set_word(W_SPINDLE_OVERRIDE, self.spindle_override)
        plc.set_word(W_RAPID_OVERRIDE, self.rapid_override)
        speed = self.spindle_speed * self.spindle_override // 10000 if self.spindle_on else 0
        plc.set_dword(D_SPINDLE_SPEED, speed)
        plc.set_dword(D_TOOL_NUMBER, self.tool)
        plc.set_dword(D_PART_COUNTER, self.part_counter)
        plc.set_dword(D_PROGRAM_STATE, int(self.program_state))
        plc.set_bit("M", M_PROGRAM_RUNNING, self.program_state == PgmState.STARTED)
        plc.set_bit("M", M_SPINDLE_ON, self.spindle_on)
        plc.set_bit("M", M_ERROR_PENDING, bool(self.errors))

    # -- program control --------------------------------------------------------------------
    @property
    def running(self) -> bool:
        """True while a program is started or stopped mid-way."""
        self.advance()
        return self._run is not None

    def select(self, wire_path: str, text: str) -> None:
        """Select a program for execution (refused with 56 while one runs)."""
        if self.running:
            raise ControlRefused(OPERATING_MODE, "a program is running")
        self.main_program = self.current_program = wire_path
        self._program_text = text
        self.current_line = 0
        self.program_state = PgmState.IDLE

    def start(self) -> None:
        """NC start: run or resume the selected program in a program-run mode."""
        self.advance()
        if self.exec_mode not in (ExecMode.SINGLE_STEP, ExecMode.AUTOMATIC):
            raise ControlRefused(OPERATING_MODE, "NC start needs a program-run mode")
        if not self.main_program:
            raise ControlRefused(OPERATING_MODE, "no program selected")
        if self._run is None:
            self._run = Run(parse_program(self._program_text))
            self._start_pos = dict(self.positions)
        run = self._run
        if self.exec_mode is ExecMode.SINGLE_STEP:
            run.stop_at = (int(run.elapsed / self.block_time) + 1) * self.block_time
        else:
            run.stop_at = None
        run.resumed_at = self.clock()
        self._last = run.resumed_at
        self.program_state = PgmState.STARTED
        self.notify(f"NC start: {self.main_program}")
        self._publish()

    def stop(self) -> None:
        """NC stop: freeze the running program (state 1)."""
        self.advance()
        if self._run is not None and self._run.resumed_at is not None:
            self._run.resumed_at = None
            self.program_state = PgmState.STOPPED
            self.notify("NC stop")
        self._publish()

    def cancel(self) -> None:
        """Abort the program (internal stop): state 3, spindle off."""
        self.advance()
        if self._run is not None:
            self._run = None
            self.program_state = PgmState.CANCELLED
            self.notify("Program cancelled")
            self.spindle_on = False
        self._publish()

    def raise_error(self, text: str, number: int = 0x0100) -> None:
        """Put a program error on the NC error list and stop the run."""
        self.advance()
        self.errors.append(NcError(3, 3, number, text))
        if self._run is not None:
            self._run = None
            self.program_state = PgmState.ERROR
        self._publish()

    def clear_errors(self) -> None:
        """CE: clear the error list."""
        self.errors.clear()
        if self.program_state == PgmState.ERROR:
            self.program_state = PgmState.ERROR_CLEARED
        self._publish()

    def set_overrides(self, feed: int, spindle: int, rapid: int) -> None:
        """Set overrides in 0.01 % (0–15000)."""
        self.advance()
        self.feed_override, self.spindle_override, self.rapid_override = (
            max(0, min(feed, 15000)),
            max(0, min(spindle, 15000)),
            max(0, min(rapid, 10000)),
        )
        self._publish()

    # -- keys -----------------------------------------------------------------------------
    def press_key(self, code: int) -> None:
        """Emulate one key press (``C_EK``)."""
        style = self.profile.keys
        if style is KeyStyle.NONE:
            raise ControlRefused(BAD_EMULATEKEY, "key emulation not supported")
        valid = _valid_new_key(code) if style is KeyStyle.NEW else _valid_old_key(code)
        if not valid:
            raise ControlRefused(BAD_EMULATEKEY, f"unknown key 0x{code:04X}")
        modes = NEW_MODE_KEYS if style is KeyStyle.NEW else OLD_MODE_KEYS
        screens = NEW_SCREEN_KEYS if style is KeyStyle.NEW else OLD_SCREEN_KEYS
        if code in modes:
            self.exec_mode = ExecMode(modes[code])
            self.screen = MODE_NAMES[modes[code]]
            self.notify(f"Operating mode: {self.screen}")
        elif code in screens:
            self.screen = screens[code]
        elif code == NC_START_KEY:
            self.start()
        elif code == NC_STOP_KEY:
            self.stop()
        elif code in (0x01AE, 0x0069):  # CE clears the error list
            self.clear_errors()

    # -- queries --------------------------------------------------------------------------
    def uptimes(self) -> dict[int, int]:
        """``R_RI`` 30–34 values in seconds."""
        self.advance()
        up = int(self._last - self.booted_at)
        return {
            30: up,
            31: up,
            32: int(self.run_seconds),
            33: int(self.spindle_seconds),
            34: 0,
        }

    def tool_info(self) -> tuple[int, int, int, float, float]:
        """(number, index, tool axis, length, radius) of the tool in the spindle."""
        self.advance()
        length, radius = self.tool_geometry(self.tool)
        axis = 0 if self.profile.lathe else 2
        return self.tool, 0, axis, length, radius
