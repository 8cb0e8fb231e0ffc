"""Family differences and session rules, checked on the wire with the project's own codec."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from opendnc.lsv2.framing import Frame, TelegramFramer
from opendnc.lsv2.payloads import DirectoryInfo, FileEntry, SystemParameters
from opendnc.sim.tnc import TncHandle, start_tnc


class Wire:
    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        self.framer = TelegramFramer()

    def ask(self, name: str, payload: bytes = b"") -> Frame:
        self.sock.sendall(TelegramFramer.encode(Frame(name, payload)))
        while (frame := self.framer.next_frame()) is None:
            data = self.sock.recv(65536)
            assert data, "closed"
            self.framer.feed(data)
        return frame

    def login(self, *names: str) -> None:
        for n in names:
            assert self.ask("A_LG", n.encode() + b"\0").mnemonic == "T_OK", n


@pytest.fixture(scope="module")
def sims(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, TncHandle]]:
    handles = {
        key: start_tnc(key, root=tmp_path_factory.mktemp(key))
        for key in ("tnc640", "itnc530", "tnc426")
    }
    yield handles
    for h in handles.values():
        h.stop()


@pytest.fixture
def wire(sims: dict[str, TncHandle], request: pytest.FixtureRequest) -> Iterator[Wire]:
    w = Wire(sims[request.param].port)
    yield w
    w.sock.close()


def err(code: int) -> bytes:
    return bytes([1, code])


@pytest.mark.parametrize("wire", ["itnc530"], indirect=True)
def test_itnc_specifics(wire: Wire) -> None:
    wire.login("INSPECT")
    pr = wire.ask("R_PR")
    assert len(pr.payload) == 124
    assert SystemParameters.from_bytes(pr.payload).max_block_length == 4096
    assert wire.ask("R_VR", b"\x06").payload == err(24)  # no release type on iTNC
    assert wire.ask("R_VR").payload.count(b"\0") == 4
    assert wire.ask("R_CI", b"\0\0\0\x03").payload == b"\0\0\0\x02\0\0\x0b\xb8"
    wire.login("FILE")
    info = DirectoryInfo.from_bytes(wire.ask("R_DI").payload)
    assert info.path == "TNC:/"
    entry = FileEntry.from_bytes(wire.ask("R_FI", b"TNC:\\\0").payload)
    assert entry.attributes & 0x40  # old scheme: directory bit
    wire.login("OSZI", "DATA")
    oc = wire.ask("R_OC")
    assert oc.mnemonic == "S_OC"
    assert len(oc.payload) == 90


@pytest.mark.parametrize("wire", ["tnc640"], indirect=True)
def test_tnc640_specifics(wire: Wire) -> None:
    wire.login("INSPECT")
    assert len(wire.ask("R_PR").payload) == 120
    assert wire.ask("R_VR").payload.count(b"\0") == 5
    assert wire.ask("R_CI", b"\0\0\0\x03").payload == err(24)
    assert wire.ask("A_LG", b"OSZI\0").payload == err(49)  # scope needs the encrypted login
    assert wire.ask("A_LG", b"DATA\0").payload == err(49)
    mp = b"\0\0\0\x01CfgDisplayLanguage.ncLanguage\0GERMAN\0"
    assert wire.ask("C_MC", mp).payload == err(23)  # parameters need PLCDEBUG
    wire.login("PLCDEBUG")
    assert wire.ask("C_MC", mp).mnemonic == "T_OK"
    assert wire.ask("R_MC", b"CfgDisplayLanguage.ncLanguage\0").payload == b"GERMAN\0"
    assert wire.ask("C_MC", b"\0\0\0\x01no.such\0x\0").payload == err(40)
    wire.login("FILE", "DNC")
    assert wire.ask("C_EK", b"\x01\xc0").payload == err(23)  # keys need MONITOR
    assert wire.ask("R_RI", b"\x00\x33").payload == err(24)  # no tool info on TNC 6xx
    assert wire.ask("R_RI", b"\x00\x1b").payload == err(24)  # no error list either
    # PLC: drive needs FILEPLC with the PLC password
    assert wire.ask("R_FI", b"PLC:\\PLCMAIN.SRC\0").payload == err(23)
    assert wire.ask("A_LG", b"FILEPLC\0wrong\0").payload == err(30)
    wire.login("FILEPLC\x00807667")
    assert wire.ask("R_FI", b"PLC:\\PLCMAIN.SRC\0").mnemonic == "S_FI"
    entry = FileEntry.from_bytes(wire.ask("R_FI", b"TNC:\\nc_prog\0").payload)
    assert entry.attributes & 0x20  # new scheme: directory bit
    # drives one per S_DR, packed listing in mode 1
    drives = [wire.ask("R_DR", b"\x02")]
    while drives[-1].mnemonic == "S_DR":
        drives.append(wire.ask("T_OK"))
    names = [FileEntry.from_bytes(f.payload).name for f in drives[:-1]]
    assert names == ["TNC:", "PLC:", "SYS:", "LOG:"]
    assert wire.ask("C_DC", b"TNC:\\nc_prog\0").mnemonic == "T_OK"
    packed = wire.ask("R_DR", b"\x01")
    assert len(FileEntry.read_all(packed.payload)) >= 3
    assert wire.ask("T_OK").mnemonic == "T_FD"


@pytest.mark.parametrize("wire", ["tnc426"], indirect=True)
def test_tnc426_specifics(wire: Wire) -> None:
    wire.login("INSPECT")
    parts = wire.ask("R_VR").payload.split(b"\0")
    assert parts[:3] == [b"TNC 426/430M", b"280476 24 ", b"GR495.07SA"]
    assert wire.ask("C_CC", b"\x00\x07").payload == err(24)  # no 4096-byte buffer
    assert wire.ask("C_CC", b"\x00\x03").mnemonic == "T_OK"  # 1024 is fine
    assert wire.ask("A_LG", b"FILESYS\0807667\0").payload == err(49)  # no SYS: drive
    wire.login("DNC", "MONITOR")
    assert wire.ask("R_RI", b"\x00\x16").payload == err(24)  # no axis read-out
    assert wire.ask("R_RI", b"\x00\x17").payload == b"\x00\x00"
    assert wire.ask("C_EK", b"\x00\x4b").mnemonic == "T_OK"  # old-style full sequence key
    assert wire.ask("R_RI", b"\x00\x17").payload == b"\x00\x04"
    assert wire.ask("C_EK", b"\x01\xc0").payload == err(39)  # new-style code refused


@pytest.mark.parametrize("wire", ["tnc640"], indirect=True)
def test_buffer_size_applies_to_downloads(wire: Wire, sims: dict[str, TncHandle]) -> None:
    root: Path = sims["tnc640"].root
    (root / "TNC" / "blocks.bin").write_bytes(bytes(range(256)) * 40)
    wire.login("INSPECT", "FILE")
    first = wire.ask("R_FL", b"TNC:\\blocks.bin\0\x01")
    assert 8 + len(first.payload) <= 256
    while wire.ask("T_OK").mnemonic == "S_FL":
        pass
    assert wire.ask("C_CC", b"\x00\x05").mnemonic == "T_OK"  # 2048
    sizes = [len(wire.ask("R_FL", b"TNC:\\blocks.bin\0\x01").payload)]
    while (f := wire.ask("T_OK")).mnemonic == "S_FL":
        sizes.append(len(f.payload))
    assert max(sizes) + 8 <= 2048
    assert max(sizes) > 1000
    assert sum(sizes) == 256 * 40
    assert wire.ask("C_FA", b"x").payload == err(24)  # exists, layout unknown
    assert wire.ask("S_VR", b"x\0").payload == err(21)  # an answer nobody asked for
