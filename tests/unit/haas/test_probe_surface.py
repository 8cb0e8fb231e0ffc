"""The virtual Haas probes like a machine: repeatability noise, height maps, no-surface alarm."""

from __future__ import annotations

import random
import statistics
from pathlib import Path

import pytest

from opendnc.errors import InputError
from opendnc.sim.haas import HeightMap, parse_surface
from opendnc.sim.haas.machine import MachineState
from opendnc.sim.haas.runner import AlarmRaised, BlockSource, ProgramRunner, RunnerEvent

PROBE = ["G65 P9832", "G00 G90 X{x} Y{y} Z0.5", "G65 P9995 W54. A20. H-1.", "M30"]


def probe(surface: object, x: float, y: float, *, metric: bool = False, noise: float = 0.0,
          seed: int = 1) -> tuple[float | None, list[RunnerEvent]]:  # fmt: skip
    machine = MachineState()
    events: list[RunnerEvent] = []
    lines = [("G21" if metric else "G20"), *(line.format(x=x, y=y) for line in PROBE)]
    runner = ProgramRunner(
        BlockSource(lines),
        machine,
        clock=lambda: 0.0,
        emit=events.append,
        surface=surface,  # type: ignore[arg-type]
        strict_probe=True,
        probe_noise_um=noise,
        rng=random.Random(seed),
    )
    runner.run()
    return machine.variables.get(5223), events


@pytest.mark.parametrize(("metric", "sigma"), [(False, 2.0 / 25400), (True, 2.0 / 1000)])
def test_noise_is_the_set_repeatability_in_program_units(metric: bool, sigma: float) -> None:
    touches = [
        probe(lambda x, y: -0.1, 0, 0, metric=metric, noise=2.0, seed=s)[0] for s in range(400)
    ]
    values = [t for t in touches if t is not None]
    assert len(values) == 400
    assert abs(statistics.fmean(values) + 0.1) < 4 * sigma / 20  # 4 standard errors
    assert 0.85 * sigma < statistics.stdev(values) < 1.15 * sigma
    exact, _ = probe(lambda x, y: -0.1, 0, 0, noise=0.0)
    assert exact == -0.1


def test_height_map_interpolates_and_has_edges(tmp_path: Path) -> None:
    path = tmp_path / "map.csv"
    path.write_text("# measured last week\nx,y,z\n0,0,0\n1,0,0.1\n0,2,0.2\n1,2,0.3\n")
    surface = parse_surface(f"csv:{path}")
    assert isinstance(surface, HeightMap)
    assert surface(0, 0) == 0.0
    assert surface(1, 2) == pytest.approx(0.3)
    assert surface(0.5, 1) == pytest.approx(0.15)  # bilinear: mean of the four corners
    assert surface(0.25, 0) == pytest.approx(0.025)
    touched, events = probe(surface, 0.5, 1.0)
    assert touched == pytest.approx(0.15)
    assert not [e for e in events if isinstance(e, AlarmRaised)]
    off, events = probe(surface, 1.5, 1.0)  # beyond the map: nothing under the stylus
    assert off is None
    (alarm,) = [e for e in events if isinstance(e, AlarmRaised)]
    assert alarm.alarm.text == "PROBE NOT TRIGGERED"
    assert "no surface under X1.5 Y1" in alarm.detail


def test_points_file_loads_as_height_map(tmp_path: Path) -> None:
    path = tmp_path / "points.csv"
    path.write_text(
        "# grid 2x2 pitch 1,1 origin 0,0 units inch\npoint,row,col,x,y,z,time,line\n"
        "1,1,1,0,0,-0.0010,t,l\n2,1,2,1,0,0.0020,t,l\n3,2,2,1,1,0,t,l\n4,2,1,0,1,0.0000,t,l\n"
    )
    surface = parse_surface(f"csv:{path}")
    assert surface(1, 0) == pytest.approx(0.002)


def test_surface_out_of_search_reach_alarms() -> None:
    touched, events = probe(lambda x, y: -2.0, 0, 0)
    assert touched is None
    (alarm,) = [e for e in events if isinstance(e, AlarmRaised)]
    assert "no surface within H-1 of Z0.5" in alarm.detail


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("x,y,z\n0,0,0\n1,0,0\n", "2 distinct X and 2 distinct Y"),
        ("x,y,z\n0,0,0\n1,0,0\n0,1,0\n", "not a full grid"),
        ("x,y,z\n0,0,a\n", "need numbers"),
        ("x,y,z\n0,0,nan\n1,1,0\n", "finite"),
    ],
)
def test_bad_height_maps(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=message):
        parse_surface(f"csv:{path}")
    with pytest.raises(InputError, match="cannot read"):
        parse_surface(f"csv:{tmp_path / 'none.csv'}")
