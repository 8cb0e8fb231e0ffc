"""The virtual Haas control: one model object that front-ends attach to.

:class:`HaasControl` owns program memory (:class:`~opendnc.sim.haas.store.ProgramStore`),
machine state and settings (:class:`~opendnc.sim.haas.machine.MachineState`), the active
:class:`~opendnc.sim.haas.runner.ProgramRunner`, the alarm list and the DPRNT routing. It does no
I/O and has no timers: front-ends call into it and a driver calls :meth:`HaasControl.step`.

Front-ends and how they attach:

* MDC over TCP (:mod:`opendnc.sim.haas.mdc_server`) calls :meth:`HaasControl.handle_mdc`;
  a serial port answering MDC (classic Setting 143) runs a ``MdcResponder`` the same way.
* DPRNT outputs implement :class:`DprntOutput` and register with :meth:`attach_dprnt`
  for a :class:`DprntDestination` (FILE, TCP, or SERIAL for a serial front-end).
* A serial front-end loads/punches programs with :meth:`save_program`/:meth:`read_program`
  (list them with ``store.numbers()``), and runs DNC through :meth:`start_dnc`: feed lines to
  the :class:`DncSession`, watch its ``backlog`` for flow control, call ``finish()`` at the
  closing ``%`` or ``link_lost()`` when the link breaks (alarm :data:`ALARM_DNC_LINK`).
* Anyone may watch alarms (:attr:`alarm_hooks`) and runner events (:attr:`event_hooks`);
  :attr:`wake` is called whenever there may be new work for the driver.

Not thread-safe: call it from one thread (the simulator's event loop).
"""

from __future__ import annotations

import enum
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from opendnc.errors import InputError
from opendnc.gcode.program import parse_header, program_lines
from opendnc.haas import mdc
from opendnc.sim.haas.machine import Alarm, MachineState, Mode, Status
from opendnc.sim.haas.runner import (
    AlarmRaised,
    BlockSource,
    CycleTimes,
    DprntLine,
    PortCode,
    ProgramRunner,
    RunnerEvent,
    StepResult,
    Surface,
)
from opendnc.sim.haas.store import ProgramStore

ALARM_DNC_LINK = Alarm(1003, "DNC LINK LOST")
"""Raised when a DNC stream breaks before its closing ``%`` (simulator's own number)."""


class DprntDestination(enum.IntEnum):
    """Setting 261 (NGC "DPRNT store location"). SERIAL (3) is the simulator's own value."""

    NONE = 0
    FILE = 1
    TCP = 2
    SERIAL = 3


class DprntOutput(Protocol):
    """Where printed DPRNT lines go; each output chooses its own line end."""

    def write_line(self, text: str) -> None:
        """One printed line, without a line end."""
        ...

    def write_control(self, code: bytes) -> None:
        """A device-control byte: DC2 for POPEN, DC4 for PCLOS (only serial sends them)."""
        ...


@dataclass
class HaasConfig:
    """Identity and behaviour knobs of a virtual control."""

    model: str = "VF-2"
    control: mdc.ControlType = mdc.ControlType.NGC
    serial_number: str = "1234567"
    software_version: str = ""
    power_on_seconds: float = 0.0
    mdc_port: int = 5051
    dprnt: DprntDestination = DprntDestination.NONE
    dprnt_file: str = ""
    dprnt_port: int = 0
    strict_probe: bool = False
    probe_noise_um: float = 1.0
    """Probe repeatability, one standard deviation in micrometres (0 = exact touches)."""
    probe_seed: int | None = None
    """Seed for the probe noise (None = different every run)."""
    ignore_first_query: bool = False
    """Fidelity knob: leave each connection's first MDC request unanswered (Haas notes the
    first ?Q100 after connecting may have to be sent twice)."""
    surface: Surface | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if not self.software_version:
            self.software_version = (
                "100.20.000.1200" if self.control is mdc.ControlType.NGC else "M18.02"
            )


class HaasControl:
    """The virtual control model (see the module docstring for how to attach to it)."""

    def __init__(
        self,
        config: HaasConfig,
        store: ProgramStore,
        *,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.config = config
        self.store = store
        self.clock = clock
        self.machine = MachineState()
        self.times = CycleTimes()
        self.runner: ProgramRunner | None = None
        self.outputs: dict[DprntDestination, list[DprntOutput]] = {}
        self.alarm_hooks: list[Callable[[Alarm, str], None]] = []
        self.event_hooks: list[Callable[[RunnerEvent], None]] = []
        self.wake: Callable[[], None] = lambda: None
        self.dprnt_dropped = 0
        self._probe_rng = random.Random(config.probe_seed)
        self._power_on_at = clock()
        settings = self.machine.settings
        settings[143] = config.mdc_port
        settings[261] = int(config.dprnt)
        settings[262] = config.dprnt_file
        settings[263] = config.dprnt_port

    # --------------------------------------------------------------- identity / clock
    @property
    def control_type(self) -> mdc.ControlType:
        """NGC or classic: decides MDC framing and where DPRNT goes."""
        return self.config.control

    def power_on_seconds(self) -> float:
        """Total power-on time (configured base + time since the model was created)."""
        return self.config.power_on_seconds + self.clock() - self._power_on_at

    def cutting_seconds(self) -> float:
        """Total run time, including the cycle in progress."""
        running = self.runner.elapsed() if self.runner and not self.runner.finished else 0.0
        return self.times.cutting_total + running

    # --------------------------------------------------------------- programs
    def save_program(self, text: str) -> int:
        """Store a program (as received over XModem or a share); returns its O number."""
        return self.store.save(text).number

    def read_program(self, number: int) -> str:
        """Tape text of a stored program (for punching)."""
        return self.store.read(number)

    @property
    def running(self) -> bool:
        """True while a runner is active (Q500 then answers ``STATUS, BUSY``)."""
        return self.runner is not None and not self.runner.finished

    def start_program(self, number: int) -> ProgramRunner:
        """Run stored program ``number`` in MEM mode (cycle start)."""
        text = self.store.read(number)
        header = parse_header(text)
        return self._start(BlockSource(program_lines(text)), header.name, Mode.MEM)

    def start_stream(self, name: str = "DNC") -> BlockSource:
        """Begin a DNC run; append lines to the returned source while they arrive.

        Prefer :meth:`start_dnc`, which also wakes the driver and tracks the backlog.
        """
        source = BlockSource(complete=False)
        self._start(source, name, Mode.DNC)
        return source

    def start_dnc(self, name: str = "DNC") -> DncSession:
        """Begin a DNC (drip-feed) run and return the session a serial front-end feeds."""
        source = self.start_stream(name)
        assert self.runner is not None  # set by start_stream
        return DncSession(self, self.runner, source)

    def _start(self, source: BlockSource, name: str, mode: Mode) -> ProgramRunner:
        if self.running:
            raise InputError("a program is already running")
        if self.machine.alarms:
            raise InputError("clear the alarms (reset) before starting a program")
        self.runner = ProgramRunner(
            source,
            self.machine,
            clock=self.clock,
            emit=self._on_event,
            surface=self.config.surface,
            times=self.times,
            name=name,
            mode=mode,
            strict_probe=self.config.strict_probe,
            probe_noise_um=self.config.probe_noise_um,
            rng=self._probe_rng,
        )
        self.wake()
        return self.runner

    def step(self) -> StepResult | None:
        """Execute one block of the active program (``None`` when nothing runs)."""
        if self.runner is None or self.runner.finished:
            return None
        self.machine.millis = (self.clock() - self._power_on_at) * 1000.0
        return self.runner.step()

    def set_mode(self, mode: Mode) -> None:
        """Change the operating mode (a front-end's key press: MDI, MEM, DNC, EDIT...)."""
        self.machine.mode = mode

    def raise_alarm(self, alarm: Alarm, detail: str = "") -> None:
        """Raise ``alarm`` (e.g. :data:`ALARM_DNC_LINK`); an active run stops."""
        if self.runner is not None and not self.runner.finished:
            self.runner.abort(alarm, detail)  # reports through _on_event
            return
        self.machine.alarms.append(alarm)
        self.machine.status = Status.ALARM
        for hook in self.alarm_hooks:
            hook(alarm, detail)

    def reset(self) -> None:
        """RESET: stop any run and clear alarms."""
        if self.runner is not None and not self.runner.finished:
            self.runner.finished = True
        self.machine.alarms.clear()
        self.machine.status = Status.IDLE

    def _on_event(self, event: RunnerEvent) -> None:
        if isinstance(event, DprntLine):
            for output in self._dprnt_outputs():
                output.write_line(event.text)
        elif isinstance(event, PortCode):
            for output in self.outputs.get(DprntDestination.SERIAL, []):
                output.write_control(event.code)
        elif isinstance(event, AlarmRaised):
            for alarm_hook in self.alarm_hooks:
                alarm_hook(event.alarm, event.detail)
        for event_hook in self.event_hooks:
            event_hook(event)

    # --------------------------------------------------------------- DPRNT routing
    def attach_dprnt(self, destination: DprntDestination, output: DprntOutput) -> None:
        """Register ``output`` to receive DPRNT lines sent to ``destination``."""
        self.outputs.setdefault(destination, []).append(output)

    def dprnt_destination(self) -> DprntDestination:
        """Where DPRNT goes now: Setting 261 on NGC; the serial port on classic.

        A classic control only prints to its serial port; the simulator still honours an
        explicit Setting 261 there (``--dprnt tcp:PORT``) so classic runs can be captured
        without a serial link.
        """
        try:
            chosen = DprntDestination(int(self.machine.settings.get(261, 0)))
        except ValueError:
            chosen = DprntDestination.NONE
        if self.control_type is mdc.ControlType.CLASSIC and chosen is DprntDestination.NONE:
            return DprntDestination.SERIAL
        return chosen

    def _dprnt_outputs(self) -> list[DprntOutput]:
        outputs = self.outputs.get(self.dprnt_destination(), [])
        if not outputs:
            self.dprnt_dropped += 1
        return outputs

    # --------------------------------------------------------------- MDC
    def handle_mdc(self, request: mdc.Request | mdc.UnknownRequest) -> mdc.Reply:
        """Answer one MDC request as the control does."""
        unknown = mdc.Refused("UNKNOWN" if self.control_type is mdc.ControlType.CLASSIC else "?")
        if isinstance(request, mdc.UnknownRequest):
            return unknown
        if isinstance(request, mdc.MacroRead):
            value = self.machine.get(request.var)
            return mdc.MacroValue(0.0 if value is None else value)
        if isinstance(request, mdc.MacroWrite):
            try:
                self.machine.set(request.var, request.value)
            except InputError:
                return mdc.Refused("?")
            return mdc.WriteAccepted()
        return self._query(request.code) or unknown

    def _query(self, code: int) -> mdc.Reply | None:
        machine = self.machine
        classic = self.control_type is mdc.ControlType.CLASSIC
        name = mdc.QUERIES.get(code, ("", None))[0]
        if code == 100:
            return mdc.TextValue(name, self.config.serial_number)
        if code == 101:
            return mdc.TextValue(name, self.config.software_version)
        if code == 102:
            return mdc.TextValue(name, self.config.model)
        if code == 104:
            mode = machine.mode
            return mdc.Mode(mode.classic() if classic else mode.value, parenthesized=classic)
        if code == 200:
            return mdc.Count(name, machine.tool_changes)
        if code == 201:
            return mdc.Count(name, machine.tool)
        if code == 300:
            return mdc.Duration(name, int(self.power_on_seconds()))
        if code == 301:
            return mdc.Duration(name, int(self.cutting_seconds()))
        if code == 303:
            return mdc.Duration(name, round(self.times.last))
        if code == 304:
            return mdc.Duration(name, round(self.times.previous))
        if code == 402:
            return mdc.Count(name, machine.m30_counter_1)
        if code == 403:
            return mdc.Count(name, machine.m30_counter_2)
        if code == 500:
            if self.running:
                return mdc.Busy()
            status = (
                "ALARM ON"
                if machine.alarms
                else ("FEED HOLD" if machine.status is Status.FEED_HOLD else "IDLE")
            )
            return mdc.ProgramStatus(machine.program, status, machine.m30_counter_1)
        return None


class DncSession:
    """One DNC run as a serial front-end sees it.

    Feed each received line with :meth:`feed_line`; call :meth:`finish` at the closing ``%``
    and :meth:`link_lost` when the link breaks first (raises :data:`ALARM_DNC_LINK`, as the
    control alarms on a broken drip-feed). :attr:`backlog` is the number of received blocks
    not executed yet: stop reading (XOFF / hold RTS) while it is above your buffer size, so
    the sender feels the control's block rate as back-pressure.
    """

    def __init__(self, control: HaasControl, runner: ProgramRunner, source: BlockSource) -> None:
        self.control = control
        self.runner = runner
        self.source = source

    @property
    def backlog(self) -> int:
        """Blocks received but not yet executed."""
        return max(0, len(self.source) - self.runner.index)

    @property
    def done(self) -> bool:
        """True once the run ended (program end, alarm or reset)."""
        return self.runner.finished

    def feed_line(self, line: str) -> None:
        """Queue one received line (without its EOB) for execution."""
        if self.source.complete:
            raise InputError("the DNC stream already ended")
        self.source.append(line)
        self.control.wake()

    def finish(self) -> None:
        """The closing ``%`` arrived: the program ends after the last block."""
        self.source.close()
        self.control.wake()

    def link_lost(self, detail: str = "link broken before the closing %") -> None:
        """The link broke mid-stream: alarm and stop (nothing happens after :meth:`finish`)."""
        if not self.source.complete and not self.runner.finished:
            self.control.raise_alarm(ALARM_DNC_LINK, detail)
