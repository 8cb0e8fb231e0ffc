"""Issue 20, item 7: the TNC 426's PLC: drive opens with FILEPLC, and a client's file search in
a lathe station's ``TNC:\\nc_prog\\ncps`` finds the program types docs/tnc-profiles.md names.

Checked with pyLSV2 1.8.0 (an independent client) and with our own client.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest

from opendnc.errors import ControlRefused
from opendnc.lsv2 import Client
from opendnc.sim.tnc import start_tnc
from tests.peers import require_module

PW = "807667"  # the publicly known default PLC code number
LATHES = ["cncpilot640", "manualplus620"]
# the regular expressions pyLSV2 ships for Klartext and ISO file names (pyLSV2.const)
KLARTEXT = r"[\$A-Za-z0-9_-]*\.[hH]$"
ISO = r"[\$A-Za-z0-9_-]*\.[iI]$"


@pytest.fixture(scope="module")
def pylsv2() -> Any:
    module = require_module("pyLSV2")
    logging.getLogger("pyLSV2").setLevel(logging.CRITICAL)
    return module


@pytest.mark.interop
def test_pylsv2_reads_tnc426_plc_drive_after_fileplc(pylsv2: Any, tmp_path: Path) -> None:
    with start_tnc("tnc426", root=tmp_path) as tnc:
        expected = (tnc.root / "PLC" / "PLCMAIN.SRC").read_bytes()
        c = pylsv2.LSV2("127.0.0.1", port=tnc.port, timeout=5, safe_mode=False)
        c.connect()
        try:
            local = tmp_path / "plcmain.src"
            # FILE alone does not open PLC:
            assert not c.recive_file("PLC:/PLCMAIN.SRC", local, binary_mode=True)
            assert not c.login(pylsv2.const.Login.FILEPLC)  # the password is needed
            assert c.login(pylsv2.const.Login.FILEPLC, PW)
            assert c.recive_file("PLC:/PLCMAIN.SRC", local, binary_mode=True)
            assert local.read_bytes() == expected
            # FILESYS stays refused: the TNC 426 has no SYS: drive
            assert not c.login(pylsv2.const.Login.FILESYS, PW)
        finally:
            c.disconnect()


def test_our_client_reads_tnc426_plc_drive_after_fileplc(tmp_path: Path) -> None:
    with start_tnc("tnc426", root=tmp_path) as tnc:
        expected = (tnc.root / "PLC" / "PLCMAIN.SRC").read_bytes()
        with Client("127.0.0.1", tnc.port, timeout=5) as c:
            with pytest.raises(ControlRefused):
                c.read_file("PLC:\\PLCMAIN.SRC", binary=True)
            c.login("FILEPLC", PW)
            assert c.read_file("PLC:\\PLCMAIN.SRC", binary=True) == expected
            names = {e.name for e in c.list_dir("PLC:\\")}
            assert {"PLCMAIN.SRC", "OEM.SYS"} <= names, names


@pytest.mark.interop
@pytest.mark.parametrize("key", LATHES)
def test_pylsv2_file_search_in_lathe_ncps(pylsv2: Any, key: str, tmp_path: Path) -> None:
    with start_tnc(key, root=tmp_path) as tnc:
        c = pylsv2.LSV2("127.0.0.1", port=tnc.port, timeout=5, safe_mode=False)
        c.connect()
        try:
            found = {}
            for label, pattern in (("H", KLARTEXT), ("I", ISO), ("nc", r".*\.nc$")):
                hits = c.get_file_list(path="TNC:/nc_prog/ncps", pattern=pattern)
                found[label] = [h.replace("/", "\\").lower() for h in hits]
            assert all(found.values()), found
            for hits in found.values():
                assert all(h.startswith("tnc:\\nc_prog\\ncps\\") for h in hits), hits
            # what pyLSV2 lists is on disk, byte for byte
            local = tmp_path / "shaft.h"
            assert c.recive_file(found["H"][0], local, binary_mode=True)
            host = tnc.root / "TNC" / Path(*found["H"][0].split("\\")[1:])
            stored = next(p for p in host.parent.iterdir() if p.name.lower() == host.name)
            assert local.read_bytes() == stored.read_bytes()
        finally:
            c.disconnect()


@pytest.mark.parametrize("key", LATHES)
def test_our_client_finds_each_program_type_in_lathe_ncps(key: str, tmp_path: Path) -> None:
    with start_tnc(key, root=tmp_path) as tnc, Client("127.0.0.1", tnc.port, timeout=5) as c:
        files = [e for e in c.walk("TNC:\\nc_prog\\ncps") if not e.is_dir]
        suffixes = {e.name.rsplit(".", 1)[-1].lower() for e in files}
        assert {"nc", "ncs", "h", "i"} <= suffixes, suffixes
        outside = [e for e in c.walk("TNC:\\") if not e.is_dir and "\\ncps\\" not in e.path]
        assert not [e for e in outside if e.name.lower().endswith((".nc", ".h", ".i"))], outside
