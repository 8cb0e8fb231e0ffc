"""The core and the command line do not import numpy, matplotlib or plotly."""

from __future__ import annotations

import subprocess
import sys


def test_cli_and_capture_stay_light() -> None:
    code = (
        "import sys, opendnc.cli.main, opendnc.surface, opendnc.surface.capture, "
        "opendnc.surface.program, opendnc.surface.measure, opendnc.sim.haas; "
        "print(sorted(m for m in ('numpy', 'matplotlib', 'plotly') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
