"""Our Client and pyLSV2 (PyPI, an independent implementation) against the same virtual TNC:
same answers, byte-identical files in both directions."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from opendnc.lsv2 import Client, MemoryType
from opendnc.sim.tnc import TncHandle, start_tnc
from tests.peers import require_module

pytestmark = pytest.mark.interop


@pytest.fixture(scope="module")
def pylsv2() -> ModuleType:
    return require_module("pyLSV2")


@pytest.fixture(scope="module", params=["tnc640", "itnc530", "tnc320"])
def tnc(request: pytest.FixtureRequest) -> Iterator[TncHandle]:
    with start_tnc(request.param) as handle:
        yield handle


@pytest.fixture
def pair(tnc: TncHandle, pylsv2: ModuleType) -> Iterator[tuple[Client, Any]]:
    theirs = pylsv2.LSV2("127.0.0.1", port=tnc.port, timeout=5, safe_mode=False)
    theirs.connect()
    with Client("127.0.0.1", tnc.port, timeout=5) as ours:
        yield ours, theirs
    theirs.disconnect()


def test_versions_and_parameters(pair: tuple[Client, Any]) -> None:
    ours, theirs = pair
    v = ours.versions
    # pyLSV2 removes blanks from the model name; we keep the string as sent
    assert (v.model.replace(" ", ""), v.nc_software, v.plc) == (
        theirs.versions.control,
        theirs.versions.nc_sw,
        theirs.versions.plc,
    )
    assert v.options == theirs.versions.option_bits
    p, q = ours.parameters, theirs.parameters
    assert (p.markers_start, p.words_start, p.strings_start, p.max_block_length) == (
        q.markers_start_address,
        q.words_start_address,
        q.strings_start_address,
        q.max_block_length,
    )
    # pyLSV2 reads max_block_length as the whole telegram (4088 -> 3072); we read it as the
    # payload, so a 4096-byte telegram fits. Where both readings agree, so must the choice.
    if p.max_block_length in (1024, 2048, 4096):
        assert ours.buffer_size == theirs._llcom._buffer_size
    else:
        assert ours.buffer_size > theirs._llcom._buffer_size
    info = ours.system_info()
    assert info.turbo_mode == q.turbo_mode_active
    assert info.dnc_allowed == q.dnc_mode_allowed
    # pyLSV2 stores -1 for "not supported", we None
    assert info.axes_sampling_rate == (None if q.axes_sampling_rate == -1 else q.axes_sampling_rate)


def test_listing_and_file_info(pair: tuple[Client, Any], tnc: TncHandle) -> None:
    ours, theirs = pair
    folder = tnc.profile.paths.program_dir
    mine = ours.list_dir(folder)
    assert theirs.change_directory(folder.replace("/", "\\"))
    their_entries = [e for e in theirs.directory_content() if e.name not in (".", "..")]
    assert sorted((e.name, e.size, e.is_dir) for e in mine) == sorted(
        (e.name, e.size, e.is_directory) for e in their_entries
    )
    for entry in mine:
        if entry.is_dir:
            continue
        info = theirs.file_info(entry.path)
        assert info.size == entry.size
        assert int(info.timestamp.timestamp()) == int(entry.modified.timestamp())
    # iTNC answers with '/' separators; pyLSV2 turns them into '\', our DirectoryInfo keeps
    # the wire text (FileInfo paths are normalised)
    assert ours.dir_info(folder).path.replace("/", "\\") == theirs.directory_info(folder).path
    assert all(e.path.startswith(folder.replace("/", "\\").rstrip("\\")) for e in mine)
    assert [d.name for d in ours.drives()] == [d.name for d in theirs.drive_info()]


@pytest.mark.parametrize("binary", [True, False])
def test_files_byte_identical_both_ways(
    pair: tuple[Client, Any], tnc: TncHandle, tmp_path: Path, binary: bool
) -> None:
    ours, theirs = pair
    if binary:
        data = os.urandom(30_000)
        name = "interop.bin"
    else:
        data = b"".join(b"%d L X+%d.5 Y-1 FMAX\r\n" % (i, i) for i in range(900))
        name = "interop.h"
    src = tmp_path / "src"
    src.write_bytes(data)
    remote_ours = f"TNC:\\ours_{name}"
    remote_theirs = f"TNC:\\theirs_{name}"
    ours.upload(src, remote_ours, binary=binary)
    assert theirs.send_file(src, remote_theirs, override_file=True, binary_mode=binary)
    # the control received the same file from both clients
    stored_ours = (tnc.root / "TNC" / f"ours_{name}").read_bytes()
    assert stored_ours == (tnc.root / "TNC" / f"theirs_{name}").read_bytes()
    a, b = tmp_path / "a", tmp_path / "b"
    ours.download(remote_theirs, a, binary=binary)
    assert theirs.recive_file(remote_ours, b, override_file=True, binary_mode=binary)
    assert a.read_bytes() == b.read_bytes() == data
    ours.delete_file(remote_ours)
    assert theirs.delete_file(remote_theirs)


def test_machine_state_same_answers(pair: tuple[Client, Any], tnc: TncHandle) -> None:
    ours, theirs = pair
    tnc.call(lambda c: c.machine.set_overrides(7500, 11000, 5000))
    assert int(ours.program_state()) == int(theirs.program_status())
    assert int(ours.execution_mode()) == int(theirs.execution_state())
    stack = theirs.program_stack()
    sel = ours.selected_program()
    assert (sel.main, sel.current, sel.line) == (stack.main, stack.current, stack.line_no)
    ov, their_ov = ours.overrides(), theirs.override_state()
    assert ov.percent == (their_ov.feed, their_ov.spindle, their_ov.rapid)
    axes = theirs.axes_location()
    if axes is not None:
        assert ours.axes_position().as_dict() == axes


def test_plc_memory_same_values(pair: tuple[Client, Any], pylsv2: ModuleType) -> None:
    ours, theirs = pair
    for ours_type, their_type, count in [
        (MemoryType.MARKER, pylsv2.MemoryType.MARKER, 300),
        (MemoryType.WORD, pylsv2.MemoryType.WORD, 130),
        (MemoryType.DWORD, pylsv2.MemoryType.DWORD, 70),
        (MemoryType.STRING, pylsv2.MemoryType.STRING, 3),
        (MemoryType.INPUT, pylsv2.MemoryType.INPUT, 10),
        (MemoryType.OUTPUT_WORD, pylsv2.MemoryType.OUTPUT_WORD, 5),
    ]:
        mine = ours.read_plc_memory(ours_type, 0, count)
        their = theirs.read_plc_memory(0, their_type, count)
        assert mine == their, ours_type


@pytest.mark.parametrize("tnc", ["itnc530"], indirect=True)  # the only family with them
def test_itnc_only_reads(pair: tuple[Client, Any], tnc: TncHandle) -> None:
    """NC errors, tool and data paths (iTNC 530 only)."""
    ours, theirs = pair
    assert ours.family.is_itnc
    tnc.call(lambda c: c.machine.raise_error("INTEROP ERROR"))
    mine = ours.nc_errors()
    their = theirs.get_error_messages()
    assert [(e.error_class, e.group, e.number, e.text) for e in mine] == [
        (e.e_class, e.e_group, e.e_number, e.e_text) for e in their
    ]
    tnc.call(lambda c: c.machine.clear_errors())
    tool, their_tool = ours.current_tool(), theirs.spindle_tool_status()
    assert (tool.number, tool.index, tool.length, tool.radius) == (
        their_tool.number,
        their_tool.index,
        their_tool.length,
        their_tool.radius,
    )
    for path in ("/PLC/memory/W/2", "/PLC/memory/D/8", "/PLC/memory/B/3"):
        assert ours.read_data_path(path) == theirs.read_data_path(path)


def test_machine_parameter(pair: tuple[Client, Any]) -> None:
    ours, theirs = pair
    name = "7230.0" if ours.family.is_itnc else "CfgDisplayLanguage.ncLanguage"
    assert ours.read_machine_parameter(name) == theirs.get_machine_parameter(name)
