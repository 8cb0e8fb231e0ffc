"""Every profile over the virtual cable against the virtual Fanuc: send, punch back,
drip-feed with DC3 back-pressure and restart, faults that end in typed errors."""

from __future__ import annotations

import contextlib
import threading
from pathlib import Path

import pytest

from opendnc.errors import DncError, TransferError
from opendnc.sim.cable import VirtualCable
from opendnc.sim.fanuc import FanucOptions, FanucParams, Mode, Selection
from opendnc.tape.codes import Code
from opendnc.tape.errors import TapeNameError
from opendnc.tape.profiles import PROFILES, Framing, get_profile
from opendnc.tape.serial_io import (
    open_tape_port,
    receive_program,
    receive_record,
    send_program,
    verify_punch,
)
from tests.sim.tape.conftest import BAUD, bench, wait_for

FAST = 2_000_000  # baud of the back-pressure tests: 181,818 characters a second
BODY = "G21\nG00 G17 G40 G80 G90\nT1 M06\nG54\nS1200 M03\nG00 X1. Y-1.5\nG01 Z-0.1 F20.\nM30\n"


def program_for(framing: Framing) -> str:
    """A program as that control keeps it: what it stores is what comes back."""
    if framing is Framing.SIEMENS:
        return "%_N_O0001_MPF\n;$PATH=/_N_MPF_DIR\n" + BODY
    if framing is Framing.FAGOR:
        return "%O0001,MX,\n" + BODY
    return "%\nO0001 (ROUND TRIP)\n" + BODY + "%\n"


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_send_and_punch_back_byte_exact(name: str, tmp_path: Path) -> None:
    profile = PROFILES[name]
    text = program_for(profile.framing)
    path = tmp_path / "O0001.nc"
    path.write_bytes(text.encode())
    options = FanucOptions(punch_back=True)
    with bench(profile, tmp_path / "mem", options=options) as b:
        kept = bytearray()
        report = send_program(b.pc, path, b.profile, keep=kept, xoff_timeout=10, linger=0.05)
        record = verify_punch(b.pc, path, b.profile, already=bytes(kept), timeout=10)
        stored = b.sim.programs()
        assert b.sim.alarms == []
    assert report.bytes_sent >= len(text)  # plus leader and trailer where the profile has them
    assert record.text == text  # the control's punch, as received: the file we sent
    assert stored == [record.name]
    assert (tmp_path / "mem" / stored[0]).read_bytes() == text.encode()


def test_eia_round_trip(tmp_path: Path) -> None:
    profile = get_profile("fanuc-0i").with_changes(code=Code.EIA, line="8N2")
    text = "%\nO0002 (EIA)\nG01 X-1.5 Y2. F100.\nM30\n%\n"
    path = tmp_path / "O0002.nc"
    path.write_text(text)
    params = FanucParams(baud=115200, code=Code.EIA)
    with bench(profile, tmp_path / "mem", params=params) as b:
        send_program(b.pc, path, b.profile, xoff_timeout=10, linger=0.05)
        wait_for(lambda: b.sim.programs() == ["O0002.nc"])
        b.sim.select(Selection(Mode.PUNCH, "O0002.nc"))
        record = receive_record(b.pc, b.profile, timeout=10)
    assert record.text == text
    assert (tmp_path / "mem" / "O0002.nc").read_text() == text


def test_drip_feed_back_pressure_and_restart(tmp_path: Path) -> None:
    # 100 kB: more than the PC's pty (64 kB) and the cable (4 kB) hold, so the PC cannot have
    # written it all before the control's first DC3; 2 Mbaud keeps the test short. The
    # control runs slower than the line: only its DC3 can hold us back.
    comment = "(" + "PASS" * 10 + ")"
    moves = [f"G01 X{i % 50}.5 Y{i % 7}.25 Z-0.{i % 9}5 F20. {comment}" for i in range(1250)]
    head = ["%", "O0003 (DNC)", "G21", "T2 M06", "G55", "S900 M03"]
    path = tmp_path / "O0003.nc"
    path.write_text("\n".join([*head, *moves, "M30", "%"]) + "\n")
    options = FanucOptions(block_rate=1500, buffer_blocks=16, resume_blocks=4)
    profile = get_profile("fanuc-0i")
    tape = Selection(Mode.TAPE)
    with bench(profile, tmp_path / "mem", options=options, baud=FAST, mode=tape) as b:
        report = send_program(b.pc, path, b.profile, drip_feed=True, safe_mode=False, linger=0.05)
        wait_for(lambda: any(m.startswith(("TAPE DONE", "ALARM")) for m in b.sim.messages))
        assert b.sim.alarms == [], b.sim.messages
        first = b.sim.executed
        restart = send_program(
            b.pc, path, b.profile, drip_feed=True, safe_mode=False, from_line=1200, linger=0.05
        )
        wait_for(lambda: sum(m.startswith("TAPE DONE") for m in b.sim.messages) == 2)
        second = b.sim.executed[len(first) :]
        assert b.sim.alarms == []
    assert report.xoffs >= 1
    # it waited for DC1 (how long depends on how the machine shares its CPU between the two)
    assert report.paused_seconds > 0
    assert first == [*head, *moves, "M30", "%"]
    assert restart.restart is not None
    preamble = list(restart.restart.preamble)
    assert preamble[:2] == ["O0003 (DNC)", "(OPENDNC RESTART AT LINE 1200)"]
    assert {"G21", "T2 M06", "G55", "S900 M03"} <= set(preamble)
    assert second == ["%", *preamble, *moves[1200 - len(head) - 1 :], "M30", "%"]


def test_send_paused_by_a_slow_memory_arrives_whole(tmp_path: Path) -> None:
    # 100 kB, more than the ptys and the cable hold, into a memory slower than the line
    blocks = "".join(
        f"G01 X{i % 50}.5 Y{i % 7}.25 (PASS {i:04d} OF THE SLOW READ)\n" for i in range(2000)
    )
    text = "%\nO0012 (SLOW)\n" + blocks + "M30\n%\n"
    path = tmp_path / "O0012.nc"
    path.write_text(text)
    options = FanucOptions(read_rate=100_000, read_buffer=256)
    with bench(get_profile("fanuc-0i"), tmp_path / "mem", options=options, baud=FAST) as b:
        report = send_program(b.pc, path, b.profile, linger=0.05)
        wait_for(lambda: b.sim.programs() == ["O0012.nc"])
        assert b.sim.alarms == []
    assert report.xoffs >= 1
    assert report.paused_seconds > 0  # it waited (how long: how the CPU is shared)
    assert (tmp_path / "mem" / "O0012.nc").read_text() == text


def test_a_sinumerik_archive_is_received_file_by_file(tmp_path: Path) -> None:
    first = "%_N_SHAFT_MPF\n;$PATH=/_N_MPF_DIR\nG0 X10\nM30\n"
    second = "%_N_HOLES_SPF\n;$PATH=/_N_SPF_DIR\nG1 X1 F100\nM17\n"
    mem = tmp_path / "mem"
    mem.mkdir()
    (mem / "ARCHIVE.MPF").write_text(first + second)
    out = tmp_path / "out"
    out.mkdir()
    with bench(get_profile("siemens-840d"), mem, mode=Selection(Mode.IDLE)) as b:
        b.sim.select(Selection(Mode.PUNCH, "ARCHIVE.MPF"))
        report = receive_program(b.pc, out, b.profile, timeout=5)
    assert [p.name for p in report.paths] == ["SHAFT.MPF", "HOLES.SPF"]
    assert (out / "SHAFT.MPF").read_text() == first
    assert (out / "HOLES.SPF").read_text() == second


def test_an_archive_with_a_bad_name_writes_none_of_its_files(tmp_path: Path) -> None:
    """The second part's name (300 characters) is refused before the first part is written."""
    first = "%_N_PARTA_MPF\n;$PATH=/_N_MPF_DIR\nG0 X10\nM30\n"
    second = f"%_N_{'B' * 300}_MPF\nG1 X1 F100\nM30\n"
    mem = tmp_path / "mem"
    mem.mkdir()
    (mem / "ARCHIVE.MPF").write_text(first + second)
    out = tmp_path / "out"
    out.mkdir()
    with bench(get_profile("siemens-840d"), mem, mode=Selection(Mode.IDLE)) as b:
        b.sim.select(Selection(Mode.PUNCH, "ARCHIVE.MPF"))
        with pytest.raises(TapeNameError, match="up to 24 characters"):
            receive_program(b.pc, out, b.profile, timeout=5)
    assert list(out.iterdir()) == []


def test_endless_feed_after_a_punch_starts_ends_in_quiet(tmp_path: Path) -> None:
    """The control's side of the cable sends DC2, a record's start, then NUL and DC1 for ever."""
    profile = get_profile("fanuc-0i").with_changes(baud=BAUD)
    out = tmp_path / "out"
    out.mkdir()
    stop = threading.Event()
    with VirtualCable(BAUD, profile.bits_per_char) as cable:
        control = open_tape_port(cable.path_a, profile)
        pc = open_tape_port(cable.path_b, profile)

        def feed_for_ever() -> None:
            control.write(b"\x12" + profile.codec().encode_text("%\nO0001\nG01 X1.\n", 0))
            while not stop.is_set():  # ~10 kB/s at 115200 baud: the PC reads it all
                control.write(b"\0\x11" * 32)

        writer = threading.Thread(target=feed_for_ever, daemon=True)
        writer.start()
        try:
            with pytest.raises(TransferError, match=r"quiet for 0\.5 s.*nothing was written"):
                receive_program(pc, out, profile, timeout=5, quiet=0.5)
        finally:
            stop.set()
            writer.join(5)
            pc.close()
            control.close()
    assert not writer.is_alive()
    assert list(out.iterdir()) == []


def test_noisy_punch_is_a_typed_error_and_no_file(tmp_path: Path) -> None:
    mem = tmp_path / "mem"
    mem.mkdir()
    (mem / "O0004.nc").write_text("%\nO0004\n" + BODY * 20 + "%\n")
    out = tmp_path / "out"
    out.mkdir()
    with bench(get_profile("fanuc-0i"), mem, mode=Selection(Mode.IDLE), noise=3e-3, seed=5) as b:
        b.sim.select(Selection(Mode.PUNCH, "O0004.nc"))
        with pytest.raises(DncError):
            receive_program(b.pc, out, b.profile, timeout=3, quiet=0.5)
    assert list(out.iterdir()) == []


def test_noisy_send_raises_th_at_the_control_and_stores_nothing(tmp_path: Path) -> None:
    path = tmp_path / "O0011.nc"
    path.write_text("%\nO0011\n" + BODY * 10 + "%\n")
    with bench(get_profile("fanuc-0i"), tmp_path / "mem", noise=2e-3, seed=3) as b:
        with contextlib.suppress(DncError):  # a DC1 the noise ate: our own typed timeout
            send_program(b.pc, path, b.profile, xoff_timeout=1.0)
        wait_for(lambda: bool(b.sim.alarms))
        assert b.sim.alarms[0].number == 1
        assert b.sim.programs() == []


def test_cut_link_is_a_typed_error_and_no_file(tmp_path: Path) -> None:
    mem = tmp_path / "mem"
    mem.mkdir()
    (mem / "O0005.nc").write_text("%\nO0005\n" + BODY * 200 + "%\n")  # ~12 kB: 1.2 s of line
    out = tmp_path / "out"
    out.mkdir()
    with bench(get_profile("fanuc-0i"), mem, mode=Selection(Mode.IDLE)) as b:
        b.sim.select(Selection(Mode.PUNCH, "O0005.nc"))
        cut = threading.Timer(0.3, b.cable.close)
        cut.start()
        with pytest.raises(TransferError, match="nothing was written"):
            receive_program(b.pc, out, b.profile, timeout=5, quiet=0.5)
        cut.join()
    assert list(out.iterdir()) == []


def _raw(b: object, data: bytes) -> None:
    pc = b.pc  # type: ignore[attr-defined]
    pc.write(data)
    pc.drain()


@pytest.mark.parametrize(
    ("wire", "alarm", "tv"),
    [
        (bytes([0xA5, 0x0A, 0x47, 0x31]), 1, False),  # '1' without its parity bit: TH
        (b"\xa5\n\xcf000\xb1\n\x47\x30\xb1\n", 2, True),  # "G01": 3 characters, TV on
        (b"\xa5\n\xcf000\xb1\nG0", 86, False),  # the data stops before the closing %
    ],
)
def test_read_alarms(wire: bytes, alarm: int, tv: bool, tmp_path: Path) -> None:
    profile = get_profile("fanuc-0i").with_changes(tv_check=tv)
    options = FanucOptions(stall_timeout=0.3)
    with bench(profile, tmp_path / "mem", options=options) as b:
        _raw(b, wire)
        wait_for(lambda: bool(b.sim.alarms))
        assert [a.number for a in b.sim.alarms] == [alarm]
        assert b.sim.programs() == []


def test_overflow_after_dc3_is_alarm_087(tmp_path: Path) -> None:
    options = FanucOptions(block_rate=10, buffer_blocks=2, resume_blocks=0, overrun_limit=40)
    with bench(get_profile("mazak-smooth"), tmp_path / "mem", options=options) as b:
        b.sim.select(Selection(Mode.TAPE))
        _raw(b, b"%\nO0006\n" + b"G01 X1.\n" * 60)  # a sender that ignores DC3
        wait_for(lambda: bool(b.sim.alarms))
        assert [a.number for a in b.sim.alarms] == [87]


def test_popen_dprnt_pclos_go_out_of_the_port(tmp_path: Path) -> None:
    mem = tmp_path / "mem"
    mem.mkdir()
    (mem / "O0007.nc").write_text(
        "%\nO0007\n#100=1.5\nPOPEN\nDPRNT[X*#100[33]]\n#100=#100+1\nDPRNT[X*#100[33]]\nPCLOS\nM30\n%\n"
    )
    with bench(get_profile("fanuc-0i"), mem, mode=Selection(Mode.IDLE)) as b:
        b.sim.run("O0007")
        record = receive_record(b.pc, b.profile, timeout=5)
    assert record.text == "X   1.500\nX   2.500\n"
    assert record.ended.value == "DC4"


RETRACT = {"fanuc": "G91 G28 Z0.", "haas": "G91 G28 Z0.", "siemens": "SUPA G0 Z0"}


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_drip_feed_restart_in_every_dialect(name: str, tmp_path: Path) -> None:
    profile = PROFILES[name]
    moves = "".join(f"G01 X{i}. Y0.5\n" for i in range(1, 9))
    text = program_for(profile.framing).replace("M30\n", moves + "M30\n")
    lines = text.splitlines()
    start = lines.index("G01 X3. Y0.5") + 1  # file line numbers are 1-based
    path = tmp_path / "O0001.nc"
    path.write_text(text)
    tape = Selection(Mode.TAPE)
    with bench(profile, tmp_path / "mem", mode=tape, options=FanucOptions(block_rate=0)) as b:
        report = send_program(
            b.pc, path, b.profile, drip_feed=True, safe_mode=False, from_line=start, linger=0.05
        )
        wait_for(lambda: any(m.startswith("TAPE DONE") for m in b.sim.messages))
        run = b.sim.executed
        assert b.sim.alarms == []
    closing = ["%"] if profile.end_at_percent else []
    tail = [line for line in lines[start - 1 :] if line != "%"]
    assert run[-len(tail) - len(closing) :] == tail + closing
    assert {"G21", "T1 M06", "G54", "S1200 M03"} <= set(run[: -len(tail)])
    retract = RETRACT.get(profile.dialect)
    if retract is None:
        assert not {"G91 G28 Z0.", "SUPA G0 Z0"} & set(run)
        assert any("retract by hand" in warning for warning in report.warnings)
    else:
        assert retract in run
    if profile.framing is Framing.SIEMENS:
        assert run[:3] == [
            "%_N_O0001_MPF",
            ";$PATH=/_N_MPF_DIR",
            f"; OPENDNC RESTART AT LINE {start}",
        ]
