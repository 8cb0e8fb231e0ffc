"""A program run on the virtual Haas, its DPRNT lines captured over real TCP and in a file."""

from __future__ import annotations

import threading
import time
from pathlib import Path

from opendnc.haas.listen import CallbackSink, CapturedLine, DprntListener, JsonlSink
from opendnc.sim.haas import DprntDestination, SimHaasThread

# plane:0.02,0,-1.25 probed at X 0, 0.5, 1.0, 1.5 with DPRNT[X#5041[44]*Y#5042[44]*Z#5223[44]]
EXPECTED = [
    "X   0.0000 Y   0.0000 Z  -1.2500",
    "X   0.5000 Y   0.0000 Z  -1.2400",
    "X   1.0000 Y   0.0000 Z  -1.2300",
    "X   1.5000 Y   0.0000 Z  -1.2200",
    "   DONE   ",
]


def wait_until(predicate: object, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():  # type: ignore[operator]
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def readers(sim: SimHaasThread) -> int:
    assert sim.sim is not None
    assert sim.sim.dprnt_tcp is not None
    out = sim.sim.dprnt_tcp
    return sim.call(lambda: len(out.readers))


def run_program(sim: SimHaasThread) -> None:
    assert sim.sim is not None
    control = sim.sim.control
    sim.call(lambda: control.start_program(321))
    wait_until(lambda: not sim.call(lambda: control.running))


def test_dprnt_over_tcp_and_file_with_reconnect(sim: SimHaasThread, tmp_path: Path) -> None:
    assert sim.sim is not None
    assert sim.sim.dprnt_tcp is not None
    got: list[CapturedLine] = []
    jsonl = JsonlSink(tmp_path / "capture.jsonl")
    listener = DprntListener(
        f"tcp://127.0.0.1:{sim.sim.dprnt_tcp.port}",
        [CallbackSink(got.append), jsonl],
        backoff_start=0.05,
    )
    thread = threading.Thread(target=listener.run, daemon=True)
    thread.start()
    try:
        wait_until(lambda: readers(sim) == 1)
        run_program(sim)
        wait_until(lambda: len(got) == len(EXPECTED))
        assert [line.text for line in got] == EXPECTED
        assert got[1].numbers == (0.5, 0.0, -1.24)

        # the control drops the reader; the listener reconnects and misses nothing after
        dprnt_out = sim.sim.dprnt_tcp
        sim.call(lambda: [w.close() for w in dprnt_out.readers])
        wait_until(lambda: listener.stats.connects == 2 and readers(sim) == 1)
        run_program(sim)
        wait_until(lambda: len(got) == 2 * len(EXPECTED))
        assert [line.text for line in got[len(EXPECTED) :]] == EXPECTED
    finally:
        listener.stop()
        thread.join(5)
        jsonl.close()
    assert len((tmp_path / "capture.jsonl").read_text().splitlines()) == 2 * len(EXPECTED)

    # Setting 261 = 1: the same program prints to the file named by Setting 262
    control = sim.sim.control
    sim.call(lambda: control.machine.settings.__setitem__(261, int(DprntDestination.FILE)))
    run_program(sim)
    path = Path(str(control.machine.settings[262]))
    assert path.read_bytes() == b"".join(line.encode() + b"\r\n" for line in EXPECTED)


def test_serial_style_output_captured_over_a_pty(tmp_path: Path) -> None:
    """StreamDprntOutput on a pty master; `dprnt listen` logic reads the slave as a port."""
    import os

    from opendnc.sim.haas.dprnt_out import StreamDprntOutput
    from opendnc.sim.haas.machine import MachineState
    from opendnc.sim.haas.program import program_lines
    from opendnc.sim.haas.runner import BlockSource, DprntLine, PortCode, ProgramRunner, RunnerEvent
    from opendnc.transport.pty import open_pty

    pty = open_pty()
    out = StreamDprntOutput(lambda data: os.write(pty.master_fd, data))

    def emit(event: RunnerEvent) -> None:
        if isinstance(event, DprntLine):
            out.write_line(event.text)
        elif isinstance(event, PortCode):
            out.write_control(event.code)

    got: list[CapturedLine] = []
    listener = DprntListener(pty.slave_path, [CallbackSink(got.append)], backoff_start=0.05)
    thread = threading.Thread(target=listener.run, kwargs={"max_lines": 2}, daemon=True)
    thread.start()
    try:
        # pyserial flushes input when it opens the port: print only once it listens
        wait_until(lambda: listener.stats.connects == 1)
        text = "%\nO00001\nPOPEN\n#1 = 2.5\nDPRNT[A#1[22]]\nDPRNT[B*#1[10]]\nPCLOS\nM30\n%"
        runner = ProgramRunner(
            BlockSource(program_lines(text)), MachineState(), clock=lambda: 0.0, emit=emit
        )
        runner.run()
        thread.join(5)
    finally:
        listener.stop()
        thread.join(5)
        pty.close()
    assert [line.text for line in got] == ["A 2.50", "B 2"]
    assert got[0].numbers == (2.5,)


def test_dnc_blocks_run_at_the_block_rate(tmp_path: Path) -> None:
    """The executor consumes a DNC stream at --block-rate, so a feeder sees the backlog."""
    from opendnc.sim.haas import HaasConfig, SimOptions
    from opendnc.sim.haas.control import DncSession

    options = SimOptions(mdc_port=None, block_rate=40.0)
    with SimHaasThread(HaasConfig(), tmp_path, options) as thread:
        assert thread.sim is not None
        control = thread.sim.control
        session: DncSession = thread.call(control.start_dnc)
        started = time.monotonic()
        thread.call(lambda: [session.feed_line(f"#1 = {i}") for i in range(10)])
        assert thread.call(lambda: session.backlog) >= 8  # 40 blocks/s: nearly all queued
        thread.call(lambda: (session.feed_line("M30"), session.finish()))
        wait_until(lambda: thread.call(lambda: session.done))
        elapsed = time.monotonic() - started
    assert elapsed >= 10 / 40.0  # 11 blocks cannot finish faster than the rate allows
    assert control.machine.get(1) == 9.0
    assert control.machine.m30_counter_1 == 1
