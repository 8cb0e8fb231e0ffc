"""Peers that stop reading or answering, on both ends of MDC (issue 15 item 2).

Server side: a real socket client that sends requests and never reads fills its receive
buffer; the virtual Haas must drop it after a bounded wait (or at once past its buffer cap),
free its slot, and never hold up the other client. Client side: a control that never answers,
or that floods other clients' replies but never ours, gives TransportTimeout, not a hang, in
the blocking and the asyncio client alike.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner, Result

from opendnc.cli.main import app
from opendnc.errors import TransportTimeout
from opendnc.haas import mdc
from opendnc.haas.mdc_client import AsyncMdcClient, MdcClient
from opendnc.sim.haas import HaasConfig, SimHaasThread, SimOptions
from opendnc.sim.haas.mdc_server import MdcServer

REQUEST = b"?Q100\r\n"


@pytest.fixture
def sim(tmp_path: Path) -> Iterator[SimHaasThread]:
    with SimHaasThread(HaasConfig(), tmp_path, SimOptions(mdc_port=0)) as thread:
        yield thread


def server_of(sim: SimHaasThread) -> MdcServer:
    assert sim.sim is not None
    assert sim.sim.mdc is not None
    return sim.sim.mdc


def wait_until(what: str, predicate: Callable[[], bool], timeout: float = 15.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


def non_reader(port: int) -> socket.socket:
    """A client with the smallest receive buffer the kernel allows, that never reads."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1)
    sock.connect(("127.0.0.1", port))
    return sock


def unread_bytes(sim: SimHaasThread, index: int) -> int:
    """Replies the server holds for its ``index``-th connection (0 when it is gone)."""
    server = server_of(sim)

    def size() -> int:
        if index >= len(server.writers):
            return 0
        return server.writers[index].transport.get_write_buffer_size()

    return sim.call(size)


def test_a_client_that_stops_reading_is_dropped_and_never_delays_the_other(
    sim: SimHaasThread,
) -> None:
    server = server_of(sim)
    sim.call(lambda: setattr(server, "drain_timeout", 3.0))
    stuck = non_reader(server.port)
    try:
        wait_until("the first session", lambda: sim.call(lambda: len(server.writers)) == 1)
        # fill its receive buffer, the server's socket buffer, then the transport's
        # high-water mark: from here on a drain() for it would wait for ever
        deadline = time.monotonic() + 20
        while unread_bytes(sim, 0) <= 64 * 1024:
            assert time.monotonic() < deadline, "could not fill the non-reading client"
            stuck.sendall(REQUEST * 500)
        started = time.monotonic()
        with MdcClient("127.0.0.1", server.port, timeout=1.0) as other:
            assert other.query(102) == mdc.TextValue("MODEL", "VF-2")
            assert time.monotonic() - started < 3.0  # answered before the stuck one was dropped
            wait_until(
                "the stuck client to be dropped", lambda: sim.call(lambda: server.dropped) == 1
            )
            assert sim.call(lambda: len(server.writers)) == 1
            # its slot is free: a new client gets in (two connections at most)
            with MdcClient("127.0.0.1", server.port, timeout=1.0) as third:
                assert third.query(102) == mdc.TextValue("MODEL", "VF-2")
            assert other.query(100) == mdc.TextValue("SERIAL NUMBER", "1234567")
    finally:
        stuck.close()


def test_a_flooding_non_reader_is_dropped_at_the_buffer_cap(sim: SimHaasThread) -> None:
    server = server_of(sim)
    sim.call(lambda: setattr(server, "drain_timeout", 600.0))  # only the cap can drop it
    stuck = non_reader(server.port)
    stuck.settimeout(5.0)
    try:
        wait_until("the first session", lambda: sim.call(lambda: len(server.writers)) == 1)
        deadline = time.monotonic() + 30
        while sim.call(lambda: server.dropped) == 0:
            assert time.monotonic() < deadline, "the flooding non-reader was never dropped"
            with contextlib.suppress(OSError):  # once dropped, the connection is reset
                stuck.sendall(REQUEST * 500)
        assert sim.call(lambda: len(server.writers)) == 0  # its slot is free
    finally:
        stuck.close()


# --------------------------------------------------------------------------- client side


class FakeControl:
    """A TCP peer that accepts one client and never answers it; with ``flood`` it keeps
    sending replies meant for some other client (as a broadcast would) and never reads."""

    def __init__(self, flood: bool) -> None:
        self.flood = flood
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port: int = self.server.getsockname()[1]
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        try:
            conn, _ = self.server.accept()
        except OSError:
            return
        with conn:
            while not self.stop.is_set():
                if not self.flood:
                    self.stop.wait(0.05)
                    continue
                try:
                    conn.sendall(b">MODEL, VF-2\r\n" * 50)
                except OSError:
                    return

    def close(self) -> None:
        self.stop.set()
        self.server.close()
        self.thread.join(timeout=10)


def outcome_within(call: Callable[[], object], seconds: float) -> BaseException | object:
    """Run ``call`` in a thread; fail the test if it has not returned within ``seconds``."""
    result: list[BaseException | object] = []

    def target() -> None:
        try:
            result.append(call())
        except BaseException as exc:
            result.append(exc)

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"the client hung for more than {seconds} s"
    return result[0]


@pytest.mark.parametrize("flood", [False, True], ids=["silent", "flooding"])
def test_blocking_client_times_out_on_a_control_that_never_answers(flood: bool) -> None:
    control = FakeControl(flood)
    try:

        def ask() -> object:
            with MdcClient("127.0.0.1", control.port, timeout=0.3) as client:
                return client.query(100)

        error = outcome_within(ask, 10.0)
        assert isinstance(error, TransportTimeout), error
        assert "asked twice" in str(error)
    finally:
        control.close()


@pytest.mark.parametrize("flood", [False, True], ids=["silent", "flooding"])
def test_async_client_times_out_on_a_control_that_never_answers(flood: bool) -> None:
    control = FakeControl(flood)
    try:

        async def main() -> object:
            async with await AsyncMdcClient.connect(
                "127.0.0.1", control.port, timeout=0.3
            ) as client:
                return await client.query(100)

        error = outcome_within(lambda: asyncio.run(main()), 10.0)
        assert isinstance(error, TransportTimeout), error
        assert "asked twice" in str(error)
    finally:
        control.close()


def test_async_client_resends_a_first_query_the_control_ignored(tmp_path: Path) -> None:
    # the blocking client's behaviour (test_mdc_tcp); the asyncio one used to give up
    config = HaasConfig(ignore_first_query=True)
    with SimHaasThread(config, tmp_path, SimOptions(mdc_port=0)) as thread:
        port = server_of(thread).port

        async def main() -> tuple[mdc.Reply, mdc.Reply]:
            async with await AsyncMdcClient.connect("127.0.0.1", port, timeout=0.3) as client:
                return await client.query(100), await client.query(102)

        first, second = asyncio.run(main())
        assert first == mdc.TextValue("SERIAL NUMBER", "1234567")
        assert second == mdc.TextValue("MODEL", "VF-2")


@pytest.mark.parametrize("flood", [False, True], ids=["silent", "flooding"])
def test_haas_q_exits_with_a_timeout_message(flood: bool) -> None:
    control = FakeControl(flood)
    try:
        args = ["haas", "q", "Q100", "--port", str(control.port), "--timeout", "0.3"]
        result = outcome_within(lambda: CliRunner().invoke(app, args), 10.0)
        assert isinstance(result, Result), result
        assert result.exit_code == 1, result.output
        assert "no MDC reply to ?Q100 within 0.3 s (asked twice)" in result.output
    finally:
        control.close()
