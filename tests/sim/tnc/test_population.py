"""Fresh roots look like the vendor's programming station of each family (docs/tnc-profiles.md).

The layouts are checked twice: on the simulator's host folders (what was written) and over the
wire with pyLSV2, an independent client (what a user sees).  The LOG: drive is checked with raw
telegrams so that exactly one login is held.
"""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from opendnc.lsv2.framing import Frame, TelegramFramer
from opendnc.sim.tnc import PROFILES, TncHandle, start_tnc
from opendnc.sim.tnc.control import Control
from opendnc.sim.tnc.machine import PgmState
from tests.peers import require_module

PW = "807667"

# Independent of population.py: the well-known layout of each family as the issue and the
# vendor's programming stations describe it (host paths below ROOT/TNC).
ITNC530_FILES = {"$MDI.H", "POCKET.H", "1001.I", "TOOL.T", "TOOL_P.TCH"}
LATHE_PROGRAMS = "nc_prog/ncps"


def host_files(root: Path) -> set[str]:
    """Every file below ROOT/TNC as a relative POSIX path."""
    base = root / "TNC"
    return {p.relative_to(base).as_posix() for p in base.rglob("*") if p.is_file()}


@pytest.fixture
def fresh(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[TncHandle]:
    with start_tnc(request.param, root=tmp_path) as handle:
        yield handle


@pytest.mark.parametrize("fresh", ["itnc530"], indirect=True)
def test_itnc530_has_programs_in_root_and_nc_prog_with_sub_folders(fresh: TncHandle) -> None:
    files = host_files(fresh.root)
    top = {f for f in files if "/" not in f}
    assert top >= ITNC530_FILES
    in_nc_prog = {f for f in files if f.startswith("nc_prog/")}
    assert in_nc_prog, "TNC:\\nc_prog is empty"
    # programs in TNC:\nc_prog sit in sub-folders, not directly in nc_prog
    assert all(f.count("/") >= 2 for f in in_nc_prog), in_nc_prog
    assert all(f.upper().endswith((".H", ".I")) for f in in_nc_prog)


@pytest.mark.parametrize("fresh", ["cncpilot640", "manualplus620"], indirect=True)
def test_lathes_keep_programs_under_ncps(fresh: TncHandle) -> None:
    programs = {f for f in host_files(fresh.root) if f.lower().endswith(".nc")}
    assert len(programs) >= 2
    assert all(f.startswith(LATHE_PROGRAMS + "/") for f in programs), programs
    assert "nc_prog/ncps/PGM01.nc" in programs
    # every program type of docs/tnc-profiles.md#paths-and-drives sits in ncps and only there
    files = host_files(fresh.root)
    for suffix in (".nc", ".ncs", ".h", ".i"):
        typed = {f for f in files if f.lower().endswith(suffix)}
        assert typed, f"no {suffix} file on a fresh lathe station"
        assert all(f.startswith(LATHE_PROGRAMS + "/") for f in typed), typed


@pytest.mark.parametrize("fresh", ["tnc640", "tnc620", "tnc320", "tnc7"], indirect=True)
def test_new_milling_stations_keep_programs_in_nc_prog(fresh: TncHandle) -> None:
    files = host_files(fresh.root)
    programs = {f for f in files if f.upper().endswith((".H", ".I"))}
    assert {"nc_prog/POCKET.H", "nc_prog/1001.I", "nc_prog/$mdi.h"} <= programs
    assert all(f.startswith("nc_prog/") for f in programs), programs
    assert {"table/tool.t", "table/tool_p.tch"} <= files


def test_itnc530_demo_program_call_resolves(tmp_path: Path) -> None:
    """POCKET.H in TNC:\\ calls a program in an nc_prog sub-folder, and the run enters it."""
    with start_tnc("itnc530", root=tmp_path) as tnc:
        pocket = (tmp_path / "TNC" / "POCKET.H").read_text("latin-1")
        call = next(line for line in pocket.splitlines() if "CALL PGM" in line)
        target = call.split("CALL PGM", 1)[1].strip()
        assert target.upper().startswith("TNC:\\NC_PROG\\")
        assert (tmp_path / "TNC" / Path(*target.split("\\")[1:])).is_file()

        def start(control: Control) -> None:
            control.select_program("TNC:\\POCKET.H")
            control.machine.block_time = 0.01
            control.machine.press_key(0x01C3)  # full sequence
            control.machine.start()

        def look(control: Control) -> tuple[str, PgmState]:
            control.machine.advance()
            return control.machine.current_program, control.machine.program_state

        tnc.call(start)
        seen: set[str] = set()
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            current, state = tnc.call(look)
            seen.add(current)
            if state is PgmState.FINISHED:
                break
            time.sleep(0.001)
        assert state is PgmState.FINISHED
        assert target in seen, seen


@pytest.fixture(scope="module")
def pylsv2() -> Any:
    module = require_module("pyLSV2")
    logging.getLogger("pyLSV2").setLevel(logging.CRITICAL)
    return module


@pytest.mark.interop
@pytest.mark.parametrize("key", list(PROFILES))
def test_pylsv2_sees_the_family_layout(pylsv2: Any, key: str, tmp_path: Path) -> None:
    """pyLSV2 lists the well-known program folder and reads the MDI program of every family."""
    with start_tnc(key, root=tmp_path) as tnc:
        paths = tnc.profile.paths
        c = pylsv2.LSV2("127.0.0.1", port=tnc.port, timeout=5, safe_mode=False)
        c.connect()
        try:
            listed = c.get_file_list(path=paths.program_dir, descend=True)
            names = {p.replace("/", "\\").lower() for p in listed}
            assert paths.mdi_program.lower() in names
            if key == "itnc530":
                assert any(n.startswith("tnc:\\nc_prog\\demo\\") for n in names), names
                assert "tnc:\\pocket.h" in names
            if tnc.profile.lathe:
                assert all(n.startswith("tnc:\\nc_prog\\ncps\\") for n in names), names
            local = tmp_path / "mdi"
            assert c.recive_file(paths.mdi_program, local, binary_mode=True)
            host = tnc.root / "TNC" / Path(*paths.mdi_program.split("\\")[1:])
            assert local.read_bytes() == host.read_bytes()
        finally:
            c.disconnect()


def _ask(sock: socket.socket, name: str, payload: bytes = b"") -> Frame:
    sock.sendall(TelegramFramer.encode(Frame(name, payload)))
    framer = TelegramFramer()
    while (frame := framer.next_frame()) is None:
        data = sock.recv(65536)
        assert data, "server closed"
        framer.feed(data)
    return frame


LOG_FILE = b"LOG:\\oem\\python\\python.log\0"


def _read_log_as(port: int, *logins: tuple[str, str]) -> Frame:
    """Log in with exactly ``logins`` and ask ``R_FI`` for the OEM Python log."""
    with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
        for name, password in logins:
            payload = name.encode() + b"\0" + (password.encode() + b"\0" if password else b"")
            assert _ask(sock, "A_LG", payload).mnemonic == "T_OK", name
        return _ask(sock, "R_FI", LOG_FILE)


def test_tnc640_grants_log_drive_to_fileplc_alone(tmp_path: Path) -> None:
    with start_tnc("tnc640", root=tmp_path) as tnc:
        assert _read_log_as(tnc.port, ("FILEPLC", PW)).mnemonic == "S_FI"
        assert _read_log_as(tnc.port, ("FILELOG", PW)).mnemonic == "S_FI"
        refused = _read_log_as(tnc.port, ("FILE", ""))
        assert (refused.mnemonic, refused.payload) == ("T_ER", bytes([1, 23]))
        # FILEPLC does not open SYS: on the way
        with socket.create_connection(("127.0.0.1", tnc.port), timeout=5) as sock:
            assert _ask(sock, "A_LG", b"FILEPLC\0" + PW.encode() + b"\0").mnemonic == "T_OK"
            sys_info = _ask(sock, "R_FI", b"SYS:\\version.txt\0")
            assert (sys_info.mnemonic, sys_info.payload) == ("T_ER", bytes([1, 23]))


def test_other_families_keep_log_behind_filelog(tmp_path: Path) -> None:
    with start_tnc("tnc620", root=tmp_path) as tnc:
        refused = _read_log_as(tnc.port, ("FILEPLC", PW))
        assert (refused.mnemonic, refused.payload) == ("T_ER", bytes([1, 23]))
        assert _read_log_as(tnc.port, ("FILELOG", PW)).mnemonic == "S_FI"


@pytest.mark.interop
def test_pylsv2_reads_log_after_fileplc_login(pylsv2: Any, tmp_path: Path) -> None:
    """What the field client does: log in as FILEPLC (pyLSV2 adds FILE) and download from LOG:."""
    with start_tnc("tnc640", root=tmp_path) as tnc:
        c = pylsv2.LSV2("127.0.0.1", port=tnc.port, timeout=5, safe_mode=False)
        c.connect()
        try:
            local = tmp_path / "python.log"
            assert not c.recive_file("LOG:/oem/python/python.log", local, binary_mode=True)
            assert c.login(pylsv2.const.Login.FILEPLC, PW)
            assert c.recive_file("LOG:/oem/python/python.log", local, binary_mode=True)
            expected = (tnc.root / "LOG" / "oem" / "python" / "python.log").read_bytes()
            assert local.read_bytes() == expected
            assert expected.startswith(b"TNC640")
        finally:
            c.disconnect()


README = Path(__file__).resolve().parents[3] / "README.md"


def _readme_lsv2_reads() -> list[str]:
    """Remote paths the README's LSV2 examples read (ls, get, table get), as typed."""
    text = README.read_text("utf-8")
    section = text.split("## Heidenhain LSV2", 1)[1].split("\n## ", 1)[0]
    block = section.split("```sh", 1)[1].split("```", 1)[0]
    paths: list[str] = []
    for line in block.splitlines():
        words = line.split("#", 1)[0].split()
        if words[:2] != ["opendnc", "lsv2"]:
            continue
        args = [w for w in words[2:] if not w.startswith("-") and w != "127.0.0.1"]
        if args[:1] in (["ls"], ["get"]) or args[:2] == ["table", "get"]:
            paths += [a for a in args if a.upper().startswith("TNC:") and not a.endswith("COPY.H")]
    return paths


def _readme_profiles() -> list[str]:
    """The profiles the README says its LSV2 paths are for."""
    text = README.read_text("utf-8")
    sentence = text.split("The paths above are those of the milling stations", 1)[1]
    sentence = sentence.split(".", 1)[0]
    return [word.strip("`, ") for word in sentence.split() if word.startswith("`")]


def test_readme_lsv2_examples_name_the_profiles_they_need(tmp_path: Path) -> None:
    reads = _readme_lsv2_reads()
    profiles = _readme_profiles()
    assert len(reads) >= 3
    assert set(profiles) == {"tnc640", "tnc620", "tnc320", "tnc7"}
    for key in PROFILES:
        with start_tnc(key, root=tmp_path / key) as tnc:
            missing = [
                p for p in reads if not (tnc.root / "TNC" / Path(*p.split("/")[1:])).exists()
            ]
        if key in profiles:
            assert not missing, (key, missing)
        else:
            assert missing, f"{key} runs every README example: list it in the README"
