"""The exception tree, and that what the package raises on purpose belongs to it."""

import re
from pathlib import Path

import pytest

import opendnc
from opendnc.errors import (
    ControlRefused,
    DncError,
    InputError,
    LocalProtocolError,
    SafetyLockError,
)
from opendnc.lsv2.constants import ErrorCode
from opendnc.lsv2.framing import Frame
from opendnc.sim.tnc.filesystem import WirePath, parse_path
from opendnc.sim.tnc.plc import PlcMemory
from opendnc.sim.tnc.profiles import PROFILES, get_profile
from opendnc.xmodem.framing import encode_block


def test_control_refused_message_names_code_and_text() -> None:
    exc = ControlRefused(32, "file not found", context="get TNC:\\x.h")
    assert isinstance(exc, DncError)
    assert str(exc) == "get TNC:\\x.h: file not found (32)"
    assert exc.code == 32


def test_safety_lock_names_the_opt_in() -> None:
    assert "--unsafe" in str(SafetyLockError("writing machine parameter X"))


# -- errors raised on purpose by public calls are DncErrors, never KeyError/ValueError -------


def test_unknown_simulator_profile_is_an_input_error() -> None:
    with pytest.raises(InputError, match="choose from"):
        get_profile("tnc999")


def test_oversized_xmodem_block_is_a_local_protocol_error() -> None:
    with pytest.raises(LocalProtocolError, match="do not fit"):
        encode_block(1, b"x" * 1025, crc=True, large=True)


@pytest.mark.parametrize("name", ["A_L", "A_LGX", "Ä_LG"])
def test_bad_telegram_name_is_a_local_protocol_error(name: str) -> None:
    with pytest.raises(LocalProtocolError, match="4 ASCII"):
        Frame(name)


def test_simulated_plc_refuses_an_unknown_bit_area() -> None:
    plc = PlcMemory(PROFILES["tnc640"].plc)
    with pytest.raises(ControlRefused) as info:
        plc.set_bit("Q", 0, True)
    assert info.value.code == ErrorCode.T_ER_BAD_MEMADR


def test_simulator_path_refusal_is_the_clients_refusal_type() -> None:
    """One refusal type: the virtual TNC refuses with what the client raises for a T_ER."""
    with pytest.raises(ControlRefused) as info:
        parse_path("C:\\x", WirePath("TNC:", ()), ("TNC:",))
    assert info.value.code == ErrorCode.T_ER_BAD_FNAME


def test_the_package_raises_no_builtin_error_on_purpose() -> None:
    """``raise KeyError(...)`` and friends in the package: each must be a DncError instead."""
    package = Path(opendnc.__file__).parent
    builtin = re.compile(
        r"\braise\s+(KeyError|ValueError|RuntimeError|TypeError|IndexError|OSError|Exception)\b"
    )
    found = [
        f"{path.relative_to(package)}:{number}: {line.strip()}"
        for path in sorted(package.rglob("*.py"))
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if builtin.search(line)
    ]
    assert found == []
