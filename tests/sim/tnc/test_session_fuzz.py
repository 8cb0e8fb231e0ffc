"""Sans-IO fuzzing of a whole session: random telegram sequences through the shared engine.

Whatever arrives, the session answers with typed messages the engine can encode (or decoding
fails with RemoteProtocolError, which the server answers or hangs up on), and closing the
session leaves no partial upload behind.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from opendnc.errors import LocalProtocolError, RemoteProtocolError
from opendnc.lsv2.connection import Lsv2Connection, Role
from opendnc.lsv2.framing import HEADER_SIZE, Frame, TelegramFramer
from opendnc.sim.tnc.control import Control
from opendnc.sim.tnc.profiles import PROFILES
from opendnc.sim.tnc.session import Session

NAMES = [
    "A_LG", "A_LO", "R_VR", "R_PR", "R_CI", "C_CC", "R_ST", "C_ST", "R_DT", "R_DI", "R_DR",
    "R_FI", "C_DC", "C_DM", "C_DD", "C_FD", "C_FC", "C_FR", "C_FL", "S_FL", "T_FD", "R_FL",
    "T_OK", "T_BD", "R_MB", "R_MC", "C_MC", "R_DP", "R_RI", "C_LK", "C_EK", "C_NC", "C_CN",
    "R_OC", "R_OP", "R_OD", "C_FA", "R_SD", "Q_QQ",
]  # fmt: skip
SAMPLES = [
    b"INSPECT\0", b"FILE\0", b"DNC\0", b"MONITOR\0", b"PLCDEBUG\0", b"DATA\0", b"OSZI\0",
    b"FILEPLC\x00807667\0", b"TNC:\\nc_prog\0", b"TNC:\\fz\\\0", b"TNC:\\fz.h\0\x01",
    b"TNC:\\fz.h\0", b"..\\..\\x\0", b"TNC:\\nc_prog\\POCKET.H\0\x00", b"\x00\x13",
    b"\x00\x07", b"\x00\x0cTNC:\\s.bmp\0", b"\x00\x1ba.log;01.01.2020;00:00:00;\0",
    b"\x00\x1a", b"\x00\x16", b"\x00\x1b", b"\x00\x33", b"\x01\xc3", b"\x00\xf0",
    b"\x00\x00\x00\x40\x10", b"\x00\x00\x00\x00\\PLC\\memory\\W\\2\0", b"\x02",
    b"\0\0\x0b\xb8\0\0\0\0\xff\xff\xff\xff",
    b"\x00\x06\xff\xff\0\0\0\0\0\0\0\0\0\0\x0b\xb8",
]  # fmt: skip
PAYLOADS = st.one_of(st.binary(max_size=40), st.sampled_from(SAMPLES))


@pytest.fixture(scope="module", params=["tnc640", "itnc530", "tnc426"])
def control(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Control:
    return Control(PROFILES[request.param], tmp_path_factory.mktemp(f"fuzz-{request.param}"))


def _drive(control: Control, telegrams: list[tuple[str, bytes]]) -> None:
    link = Lsv2Connection(Role.SERVER)
    session = Session(control, link)
    try:
        for name, payload in telegrams:
            link.receive_data(TelegramFramer.encode(Frame(name, payload)))
            try:
                request = link.next_event()
            except RemoteProtocolError:
                continue  # the server answers T_ER (or hangs up); the session never sees it
            assert request is not None
            result = session.handle(request, HEADER_SIZE + len(payload))
            for message in [*result.frames, *(d.make() for d in result.deferred)]:
                if message is None:
                    continue
                # The server replaces an answer too big for the buffer with T_ER.
                with contextlib.suppress(LocalProtocolError):
                    link.send(message)
    finally:
        session.close()


@settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(st.lists(st.tuples(st.sampled_from(NAMES), PAYLOADS), max_size=25))
def test_random_sessions_stay_well_formed(
    control: Control, telegrams: list[tuple[str, bytes]]
) -> None:
    _drive(control, [("A_LG", b"INSPECT\0"), ("A_LG", b"FILE\0"), *telegrams])
    root: Path = control.root
    assert not list((root / ".partial").iterdir())
    allowed = {"TNC", "PLC", "SYS", "LOG", ".partial", ".state"}
    assert {p.name for p in root.iterdir()} <= allowed
