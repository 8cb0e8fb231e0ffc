"""`opendnc serial send` and `serial recv` end to end over the virtual cable: the options that
change the profile (here --code and --baud) reach each command's port and codec."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from opendnc.sim.cable import VirtualCable
from opendnc.sim.fanuc import FanucParams, Mode, Selection, VirtualFanuc
from opendnc.tape.codes import Code
from opendnc.tape.profiles import get_profile
from tests.sim.tape.conftest import BAUD, wait_for

CLI = [sys.executable, "-m", "opendnc.cli.main", "serial"]
TEXT = "%\nO0002 (EIA BY THE CLI)\nG01 X-1.5 Y2. F100.\nM30\n%\n"


def test_eia_send_and_punch_through_the_cli(tmp_path: Path) -> None:
    path = tmp_path / "O0002.nc"
    path.write_text(TEXT)
    out = tmp_path / "in"
    out.mkdir()
    ready = tmp_path / "ready"
    # fanuc-0i is ISO at 9600 baud: the control here punches EIA at 115200, so a receive that
    # lost --code or --baud on the way to its port reads nothing it can decode
    line = get_profile("fanuc-0i").with_changes(code=Code.EIA, line="8N2", baud=BAUD)
    changes = ["--code", "eia", "--baud", str(BAUD)]
    with VirtualCable(BAUD, line.bits_per_char) as cable:
        params = FanucParams(baud=BAUD, code=Code.EIA)
        with VirtualFanuc(cable.path_a, tmp_path / "mem", profile=line, params=params) as sim:
            send = [*CLI, "send", str(path), "--port", cable.path_b, *changes, "--json"]
            sent = subprocess.run(send, capture_output=True, text=True, timeout=60, check=False)
            assert sent.returncode == 0, sent.stderr
            wait_for(lambda: sim.programs() == ["O0002.nc"])
            recv = [*CLI, "recv", str(out), "--port", cable.path_b, *changes, "--json"]
            recv += ["--timeout", "30", "--ready-file", str(ready)]
            with subprocess.Popen(
                recv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
            ) as receiving:
                wait_for(ready.exists, 30)
                sim.select(Selection(Mode.PUNCH, "O0002.nc"))
                stdout, stderr = receiving.communicate(timeout=60)
            assert receiving.returncode == 0, stderr
            assert sim.alarms == []
    assert json.loads(sent.stdout)["sent"]["bytes_sent"] >= len(TEXT)
    assert (tmp_path / "mem" / "O0002.nc").read_text() == TEXT
    received = json.loads(stdout)
    assert Path(received["path"]).read_text() == TEXT
    assert received["ended"] != "quiet"
