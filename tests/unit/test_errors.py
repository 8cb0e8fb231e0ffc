from opendnc.errors import ControlRefused, DncError, SafetyLockError


def test_control_refused_message_names_code_and_text() -> None:
    exc = ControlRefused(32, "file not found", context="get TNC:\\x.h")
    assert isinstance(exc, DncError)
    assert str(exc) == "get TNC:\\x.h: file not found (32)"
    assert exc.code == 32


def test_safety_lock_names_the_opt_in() -> None:
    assert "--unsafe" in str(SafetyLockError("writing machine parameter X"))
