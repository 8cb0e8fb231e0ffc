"""A virtual Haas on a background loop thread, bound to loopback port 0."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from opendnc.haas.mdc import ControlType
from opendnc.sim.haas import DprntDestination, HaasConfig, SimHaasThread, SimOptions, parse_surface

PROBE_PROGRAM = """%
O00321 (SURFACE MAP)
G00 G90 G54 X0 Y0
#100 = 0
WHILE [#100 LT 4] DO1
G65 P9995 W54. A20. H-1.
DPRNT[X#5041[44]*Y#5042[44]*Z#5223[44]]
G00 G91 X.5
#100 = #100 + 1
END1
DPRNT[***DONE***]
T2 M06
M30
%
"""


@pytest.fixture(params=list(ControlType), ids=lambda c: c.value)
def control_type(request: pytest.FixtureRequest) -> ControlType:
    return request.param  # type: ignore[no-any-return]


@pytest.fixture
def sim(tmp_path: Path, control_type: ControlType) -> Iterator[SimHaasThread]:
    (tmp_path / "mem").mkdir()
    (tmp_path / "mem" / "O00321.nc").write_text(PROBE_PROGRAM)
    config = HaasConfig(
        control=control_type,
        surface=parse_surface("plane:0.02,0,-1.25"),
        probe_noise_um=0.0,  # exact touches: the tests compare printed digits
        dprnt=DprntDestination.TCP,
    )
    options = SimOptions(mdc_port=0, dprnt_tcp_port=0, dprnt_file=tmp_path / "dprnt.txt")
    with SimHaasThread(config, tmp_path / "mem", options) as thread:
        yield thread
