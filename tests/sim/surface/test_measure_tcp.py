"""End to end over Ethernet: Net Share load, DPRNT over TCP, capture, report (NGC)."""

from __future__ import annotations

import json
from pathlib import Path

from opendnc.haas.dprnt import parse_line
from opendnc.surface.points import read_points

from .conftest import GRID, GRID_ARGS, SIGMA_IN, Haas, analytic, dprnt_port, run_until, surface


def start_when_reader(haas: Haas, number: int) -> None:
    sim = haas.thread.sim
    assert sim is not None
    assert sim.dprnt_tcp is not None
    reader = sim.dprnt_tcp
    assert haas.thread._submit(reader.wait_reader(10.0), timeout=15)
    haas.start(number)


def check_points(points: Path, printed: list[str]) -> None:
    """Every grid point recovered exactly as printed, and within noise of the true surface."""
    rows = read_points(points).rows
    assert sorted(r.point for r in rows) == list(range(1, GRID.size + 1))
    by_number = {}
    for text in printed:
        parsed = parse_line(text)
        if parsed.get("P") is not None:
            by_number[int(parsed.get("P") or 0)] = text
    for row in rows:
        point = GRID.point(row.point)
        assert (row.x, row.y, row.row, row.col) == (point.x, point.y, point.row, point.col)
        assert row.line == by_number[row.point]  # the control's own line, not a neighbour's
        assert row.z_text == by_number[row.point].split("Z")[-1].strip()
        # printed to 1e-4 in: rounding (half a step) plus the probe's repeatability
        assert abs(row.z - surface(row.x, row.y)) <= 0.5e-4 + 5 * SIGMA_IN


def test_measure_over_net_share_and_dprnt_tcp(tcp_haas: Haas, tmp_path: Path) -> None:
    report = tmp_path / "out" / "report.html"
    report.parent.mkdir()
    result = run_until(
        [
            "surface",
            "measure",
            "--haas",
            "127.0.0.1",
            "--share",
            str(tcp_haas.root),
            "--dprnt-port",
            str(dprnt_port(tcp_haas)),
            *GRID_ARGS,
            "--number",
            "O04321",
            "-o",
            str(report),
            "--png",
            str(tmp_path / "out" / "map.png"),
            "--timeout",
            "30",
            "--json",
        ],
        "waiting for cycle start",
        lambda: start_when_reader(tcp_haas, 4321),
    )
    assert result.returncode == 0, result.stderr
    assert (tcp_haas.root / "O04321.nc").exists()  # loaded through the share, not by us
    check_points(report.with_suffix(".csv"), tcp_haas.printed)
    summary = json.loads(result.stdout)
    want = analytic(GRID)
    assert abs(summary["tilt"]["x"]["slope"] - want["a"]) < 2e-4
    assert abs(summary["tilt"]["y"]["slope"] - want["b"]) < 2e-4
    assert abs(summary["flatness"] - want["flatness"]) < 2e-4
    assert summary["missing"] == []
    assert report.read_text().startswith("<!DOCTYPE html>")


class DropOne:
    """Wraps a DPRNT output and loses the line for one point (a dropped line)."""

    def __init__(self, inner: object, point: int) -> None:
        self.inner = inner
        self.point = point
        self.dropped: list[str] = []

    def write_line(self, text: str) -> None:
        if parse_line(text).get("P") == self.point:
            self.dropped.append(text)
            return
        self.inner.write_line(text)  # type: ignore[attr-defined]

    def write_control(self, code: bytes) -> None:
        self.inner.write_control(code)  # type: ignore[attr-defined]


def test_dropped_line_is_reported_missing_never_shifted(tcp_haas: Haas, tmp_path: Path) -> None:
    program = tmp_path / "O01234.nc"
    made = run_until(["surface", "program", *GRID_ARGS, "-o", str(program)], "", lambda: None)
    assert made.returncode == 0, made.stderr
    (tcp_haas.root / "O01234.nc").write_text(program.read_text())
    control = tcp_haas.control
    from opendnc.sim.haas import DprntDestination

    def wrap() -> DropOne:
        outputs = control.outputs[DprntDestination.TCP]
        outputs[0] = DropOne(outputs[0], 13)  # type: ignore[assignment]
        return outputs[0]  # type: ignore[return-value]

    dropper = tcp_haas.thread.call(wrap)
    points = tmp_path / "points.csv"
    result = run_until(
        [
            "surface",
            "capture",
            "--port",
            f"tcp://127.0.0.1:{dprnt_port(tcp_haas)}",
            "--program",
            str(program),
            "-o",
            str(points),
            "--timeout",
            "30",
        ],
        "listening on",
        lambda: start_when_reader(tcp_haas, 1234),
    )
    assert len(dropper.dropped) == 1
    assert result.returncode == 2, result.stderr
    assert "missing: point 13 (before 14)" in result.stderr
    assert "47 of 48 points" in result.stderr
    rows = {r.point: r for r in read_points(points).rows}
    assert 13 not in rows
    printed = {int(parse_line(t).get("P") or 0): t for t in tcp_haas.printed if t.startswith("P")}
    for number in (12, 14):  # the neighbours keep their own values
        assert rows[number].line == printed[number]
    # resume after the operator reruns the program: only the missing point is added
    tcp_haas.wait_idle()
    control_ref = tcp_haas.control
    tcp_haas.thread.call(
        lambda: control_ref.outputs[DprntDestination.TCP].__setitem__(0, dropper.inner)
    )  # type: ignore[arg-type]
    resumed = run_until(
        [
            "surface",
            "capture",
            "--port",
            f"tcp://127.0.0.1:{dprnt_port(tcp_haas)}",
            "--program",
            str(program),
            "-o",
            str(points),
            "--resume",
            "--timeout",
            "30",
        ],
        "listening on",
        lambda: start_when_reader(tcp_haas, 1234),
    )
    assert resumed.returncode == 0, resumed.stderr
    rows_after = read_points(points).rows
    assert sorted(r.point for r in rows_after) == list(range(1, 49))
    assert [r.point for r in rows_after].count(13) == 1
