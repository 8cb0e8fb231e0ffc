"""A server killed with SIGKILL writes nothing at its end; after the restart the status
timeline still shows the time it was down as no record, not as the last state stretched over
the gap."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path

import pytest

from opendnc.server.core.state import State
from opendnc.server.machines.timeline import Timeline
from opendnc.server.store.db import make_engine, make_sessions
from opendnc.server.store.models import StatusSample, utcnow
from opendnc.sim.fleet import server_config
from tests.server.harness import Procs, serve, wait_for
from tests.server.test_from_the_control import FleetThread


@pytest.fixture
def tnc(tmp_path: Path) -> Iterator[FleetThread]:
    fleet = FleetThread(tmp_path / "machines", tnc=1, haas=0)
    try:
        yield fleet
    finally:
        fleet.stop()


def test_a_killed_server_leaves_a_no_record_gap_the_timeline_shows(
    tmp_path: Path, tnc: FleetThread, procs: Procs, db_url: str
) -> None:
    config = tmp_path / "shop.toml"
    config.write_text(
        server_config(tnc.fleet, poll_interval=0.3, library=tmp_path / "lib", check="warn")
    )
    engine = make_engine(db_url)
    sessions = make_sessions(engine)
    try:
        serve(procs, config, db_url)

        def samples() -> list[tuple[str, str]]:
            with sessions() as session:
                rows = session.query(StatusSample).order_by(StatusSample.at, StatusSample.id)
                return [(r.machine, r.state) for r in rows]

        wait_for(
            "the TNC's state and the heartbeat written",
            lambda: {("tnc-1", "ready"), ("@opendnc", "alive")} <= set(samples()),
            describe=samples,
        )
        procs.stop("server", signal.SIGKILL)
        killed = utcnow()
        assert samples()[-1] != ("tnc-1", "no_record")  # a killed server wrote no end
        time.sleep(1.0)  # down for a while
        serve(procs, config, db_url)
        wait_for(
            "a ready state after the restart",
            lambda: [s for m, s in samples() if m == "tnc-1"][-2:] == ["no_record", "ready"],
            describe=samples,
        )
        timeline = Timeline(sessions)
        history = timeline.history("tnc-1", killed - timedelta(hours=1))
        gap = [s for s in history if s.state is State.NO_RECORD]
        assert len(gap) == 1
        assert gap[0].at <= killed  # from the last heartbeat before the kill
        assert killed - gap[0].at < timedelta(seconds=35)
        strip = timeline.segments("tnc-1", hours=1)
        assert "no record (server stopped)" in [s.label for s in strip]
        assert [s.state for s in strip][-2:] == ["no_record", "ready"]
    finally:
        engine.dispose()
