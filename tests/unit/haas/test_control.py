"""The virtual control model without any sockets: MDC answers, DPRNT routing, alarms."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from opendnc.errors import InputError
from opendnc.haas import mdc
from opendnc.sim.haas.control import (
    ALARM_DNC_LINK,
    DprntDestination,
    HaasConfig,
    HaasControl,
)
from opendnc.sim.haas.machine import Alarm
from opendnc.sim.haas.runner import StepResult
from opendnc.sim.haas.store import ProgramStore
from opendnc.sim.haas.surface import parse_surface


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class Capture:
    def __init__(self) -> None:
        self.lines: list[str] = []
        self.codes: list[bytes] = []

    def write_line(self, text: str) -> None:
        self.lines.append(text)

    def write_control(self, code: bytes) -> None:
        self.codes.append(code)


def make(tmp_path: Path, **kwargs: object) -> tuple[HaasControl, Clock]:
    clock = Clock()
    kwargs.setdefault("probe_noise_um", 0.0)  # exact touches: the tests compare printed digits
    config = HaasConfig(**kwargs)  # type: ignore[arg-type]
    return HaasControl(config, ProgramStore(tmp_path), clock=clock), clock


def ask(control: HaasControl, line: str) -> str:
    return control.handle_mdc(mdc.parse_request(line)).to_payload()


def test_every_query_answers_ngc(tmp_path: Path) -> None:
    control, clock = make(tmp_path, power_on_seconds=3600.0)
    clock.now = 61.0
    assert ask(control, "?Q100") == "SERIAL NUMBER, 1234567"
    assert ask(control, "?Q101").startswith("SOFTWARE VERSION, ")
    assert ask(control, "?Q102") == "MODEL, VF-2"
    assert ask(control, "?Q104") == "MODE, MDI"
    assert ask(control, "?Q200") == "TOOL CHANGES, 0"
    assert ask(control, "?Q201") == "USING TOOL, 0"
    assert ask(control, "?Q300") == "P.O. TIME, 00001:01:01"
    assert ask(control, "?Q301") == "C.S. TIME, 00000:00:00"
    assert ask(control, "?Q303") == "LAST CYCLE, 00000:00:00"
    assert ask(control, "?Q304") == "PREV CYCLE, 00000:00:00"
    assert ask(control, "?Q402") == "M30 #1, 0"
    assert ask(control, "?Q403") == "M30 #2, 0"
    assert ask(control, "?Q500") == "PROGRAM, MDI, IDLE, PARTS, 0"
    assert ask(control, "?Q600 100") == "MACRO, 0.0"
    assert ask(control, "?Q999") == "?"
    assert ask(control, "?q100") == "?"


def test_classic_differences(tmp_path: Path) -> None:
    control, _ = make(tmp_path, control=mdc.ControlType.CLASSIC)
    assert ask(control, "?Q104") == "MODE, (MDI)"
    assert ask(control, "?Q999") == "UNKNOWN"
    assert ask(control, "?q500") == "UNKNOWN"


def test_macro_write_and_refusal(tmp_path: Path) -> None:
    control, _ = make(tmp_path)
    assert ask(control, "?E10100 1.5") == "!"
    assert ask(control, "?Q600 10100") == "MACRO, 1.5"
    assert ask(control, "?E5021 1") == "?"  # machine position is read-only


def test_run_counts_times_and_busy(tmp_path: Path) -> None:
    control, clock = make(tmp_path)
    control.save_program("%\nO00123 (PART)\nT4 M06\nDPRNT[DONE]\nM30\n%\n")
    control.start_program(123)
    assert ask(control, "?Q500") == "STATUS, BUSY"
    assert ask(control, "?Q104") == "MODE, MEM"
    clock.now = 13.0
    while control.step() is StepResult.RAN:
        pass
    assert ask(control, "?Q500") == "PROGRAM, O00123, IDLE, PARTS, 1"
    assert ask(control, "?Q303") == "LAST CYCLE, 00000:00:13"
    assert ask(control, "?Q301") == "C.S. TIME, 00000:00:13"
    assert ask(control, "?Q201") == "USING TOOL, 4"
    assert ask(control, "?Q200") == "TOOL CHANGES, 1"
    assert ask(control, "?Q402") == "M30 #1, 1"


def test_dprnt_routing_follows_setting_261(tmp_path: Path) -> None:
    control, _ = make(tmp_path, dprnt=DprntDestination.TCP)
    tcp, file, serial = Capture(), Capture(), Capture()
    control.attach_dprnt(DprntDestination.TCP, tcp)
    control.attach_dprnt(DprntDestination.FILE, file)
    control.attach_dprnt(DprntDestination.SERIAL, serial)
    source = control.start_stream()
    for line in ["POPEN", "DPRNT[ONE]"]:
        source.append(line)
    while control.step() is StepResult.RAN:
        pass
    assert tcp.lines == ["ONE"]
    assert serial.codes == [b"\x12"]
    control.machine.settings[261] = 1
    source.append("DPRNT[TWO]")
    control.step()
    assert file.lines == ["TWO"]
    control.machine.settings[261] = 0
    source.append("DPRNT[LOST]")
    control.step()
    assert control.dprnt_dropped == 1


def test_classic_prints_to_serial(tmp_path: Path) -> None:
    control, _ = make(tmp_path, control=mdc.ControlType.CLASSIC)
    serial = Capture()
    control.attach_dprnt(DprntDestination.SERIAL, serial)
    source = control.start_stream()
    source.append("DPRNT[HELLO]")
    control.step()
    assert serial.lines == ["HELLO"]


def test_dnc_link_alarm_and_reset(tmp_path: Path) -> None:
    control, _ = make(tmp_path)
    seen: list[tuple[Alarm, str]] = []
    control.alarm_hooks.append(lambda alarm, detail: seen.append((alarm, detail)))
    source = control.start_stream("DNC")
    source.append("G00 X1")
    assert control.step() is StepResult.RAN
    assert control.step() is StepResult.WAITING
    control.raise_alarm(ALARM_DNC_LINK, "serial link dropped")
    assert seen == [(ALARM_DNC_LINK, "serial link dropped")]
    assert ask(control, "?Q500") == "PROGRAM, DNC, ALARM ON, PARTS, 0"
    with pytest.raises(InputError, match="alarm"):
        control.start_stream()
    control.reset()
    assert ask(control, "?Q500") == "PROGRAM, DNC, IDLE, PARTS, 0"


def test_probe_program_with_surface(tmp_path: Path) -> None:
    control, _ = make(tmp_path, surface=parse_surface("plane:0.1,0,-2"))
    control.save_program("%\nO00001\nG00 X2 Y0\nG65 P9995 W54. A20. H-1.\nM30\n%")
    control.start_program(1)
    while control.step() is StepResult.RAN:
        pass
    assert ask(control, "?Q600 5223") == "MACRO, -1.8"


def test_store_roundtrip_and_errors(tmp_path: Path) -> None:
    store = ProgramStore(tmp_path / "mem")
    header = store.save("O01234 (X)\nG00 X1\nM30")
    assert header.number == 1234
    assert store.numbers() == [1234]
    assert store.read(1234) == "%\nO01234 (X)\nG00 X1\nM30\n%\n"
    assert not [p for p in (tmp_path / "mem").iterdir() if p.name.startswith(".tmp")]
    with pytest.raises(InputError):
        store.read(5)
    with pytest.raises(InputError):
        store.save("G00 X1")
    store.delete(1234)
    assert store.numbers() == []


@pytest.mark.parametrize(
    ("spec", "x", "y", "z"),
    [
        ("flat:-1", 5, 5, -1),
        ("plane:0.5,0.25,-1", 2, 4, 1),
        ("sine:2,4", 1, 0, 2),
        ("sine:2,4", 1, 2, -2),
        ("sine:2,4,1", 0, 1, 1),
        ("wave:1,4,-1", 1, 9, 0),
        ("bowl:1,2", 0, 0, -1),
        ("bowl:1,2,5,5,3", 5, 6, 2.25),
        ("bowl:1,2", 3, 0, 0),
    ],
)
def test_surfaces(spec: str, x: float, y: float, z: float) -> None:
    surface = parse_surface(spec)
    assert surface(x, y) == pytest.approx(z)
    assert parse_surface(str(surface)) == surface


@pytest.mark.parametrize(
    "spec", ["", "plane", "plane:1,2", "cone:1", "sine:1,0", "flat:x", "bowl:1,2,3", "flat:nan"]
)
def test_bad_surfaces(spec: str) -> None:
    with pytest.raises(InputError):
        parse_surface(spec)


@pytest.mark.parametrize(
    ("spec", "expected"),
    [
        (None, (DprntDestination.NONE, None, None)),
        ("serial", (DprntDestination.SERIAL, None, None)),
        ("tcp:0", (DprntDestination.TCP, 0, None)),
        ("file", (DprntDestination.FILE, None, Path("root/dprnt.txt"))),
        ("file:/tmp/x.txt", (DprntDestination.FILE, None, Path("/tmp/x.txt"))),
    ],
)
def test_parse_dprnt_option(spec: str | None, expected: object) -> None:
    from opendnc.cli.sim_haas import parse_dprnt

    assert parse_dprnt(spec, Path("root")) == expected


@pytest.mark.parametrize("spec", ["tcp", "tcp:x", "serial:1", "printer"])
def test_bad_dprnt_option(spec: str) -> None:
    from opendnc.cli.sim_haas import parse_dprnt

    with pytest.raises(InputError):
        parse_dprnt(spec, Path("root"))


def test_dnc_session_backlog_finish_and_link_loss(tmp_path: Path) -> None:
    control, _ = make(tmp_path)
    woken: list[int] = []
    control.wake = lambda: woken.append(1)
    session = control.start_dnc()
    for line in ["#1 = 1", "#1 = #1 + 1", "DPRNT[V#1[10]]"]:
        session.feed_line(line)
    assert session.backlog == 3
    assert control.step() is StepResult.RAN
    assert session.backlog == 2
    assert ask(control, "?Q104") == "MODE, DNC"
    while control.step() is StepResult.RAN:
        pass
    assert session.backlog == 0
    session.feed_line("M30")
    session.finish()
    session.link_lost()  # after the closing %: no alarm
    while control.step() is StepResult.RAN:
        pass
    assert session.done
    assert not control.machine.alarms
    assert len(woken) >= 5
    with pytest.raises(InputError):
        session.feed_line("G00 X1")

    broken = control.start_dnc()
    broken.feed_line("G00 X1")
    broken.link_lost("cable pulled")
    assert control.machine.alarms == [ALARM_DNC_LINK]
    assert broken.done
    assert ask(control, "?Q500") == "PROGRAM, DNC, ALARM ON, PARTS, 1"


def test_mdc_responder_for_any_link(tmp_path: Path) -> None:
    from opendnc.sim.haas.mdc_server import MdcResponder

    control, _ = make(tmp_path, control=mdc.ControlType.CLASSIC, ignore_first_query=True)
    responder = MdcResponder(control)
    assert responder.feed(b"?Q100\r\n") == []  # the first request goes unanswered
    assert responder.feed(b"?Q10") == []
    assert responder.feed(b"2\r\n?Q999\n") == [
        b"\x02MODEL, VF-2\x17\r\n>",
        b"\x02UNKNOWN\x17\r\n>",
    ]
    assert responder.feed(b"x" * 2000) == [b"\x02UNKNOWN\x17\r\n>"]  # garbage, no line end


def test_reference_example_session_bytes(tmp_path: Path) -> None:
    """docs/haas.md#mdc-example, byte for byte (NGC)."""
    from opendnc.sim.haas.mdc_server import MdcResponder

    control, _ = make(tmp_path)
    control.machine.program = "O00123"
    control.machine.m30_counter_1 = 380
    control.machine.variables[5223] = -2.531
    responder = MdcResponder(control)
    assert responder.feed(b"?Q100\r\n") == [b">SERIAL NUMBER, 1234567\r\n"]
    assert responder.feed(b"?Q500\r\n") == [b">PROGRAM, O00123, IDLE, PARTS, 380\r\n"]
    assert responder.feed(b"?Q600 5223\r\n") == [b">MACRO, -2.531\r\n"]
    assert responder.feed(b"?E10100 1.5\r\n") == [b">!\r\n"]
    assert control.machine.get(10100) == 1.5


def test_seed_surface_snippet(tmp_path: Path) -> None:
    """The grid-probing snippet of the OpenDNC README (docs/haas.md#sources), EOB semicolons and
    all."""
    control, _ = make(tmp_path, surface=parse_surface("plane:-0.1,0,-0.5"))
    serial = Capture()
    control.machine.settings[261] = int(DprntDestination.SERIAL)
    control.attach_dprnt(DprntDestination.SERIAL, serial)
    session = control.start_dnc()
    for _ in range(2):
        session.feed_line("G65 P9995 W54. A20. H-1.;")
        session.feed_line("DPRNT[#5223[44]];")
        session.feed_line("G00 G91 X.5;")
    session.feed_line("DPRNT[Z Offset is #5223[44]];")
    session.finish()
    while control.step() is StepResult.RAN:
        pass
    # the last print follows a move without a probe: #5223 still holds the second touch
    assert serial.lines == ["  -0.5000", "  -0.5500", "Z Offset is   -0.5500"]


def test_stored_program_gets_umask_permissions(tmp_path: Path) -> None:
    store = ProgramStore(tmp_path)
    old = os.umask(0o027)
    try:
        store.save("O01000\nM30")
    finally:
        os.umask(old)
    assert stat.S_IMODE(store.path(1000).stat().st_mode) == 0o640
    assert [p.name for p in tmp_path.iterdir()] == ["O01000.nc"]
