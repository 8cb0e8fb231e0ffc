"""The shared CLI output helpers print user text literally."""

from __future__ import annotations

import pytest
import typer

from opendnc.cli import common
from opendnc.errors import InputError


def test_error_line_keeps_colon_words_literal(capsys: pytest.CaptureFixture[str]) -> None:
    # rich would turn ":X:" into an emoji; an error must quote the user's input as typed
    with pytest.raises(typer.Exit) as stopped, common.cli_errors():
        raise InputError("bad signal '0:X:1'")
    assert stopped.value.exit_code == 1
    err = capsys.readouterr().err
    assert "'0:X:1'" in err


def test_console_keeps_colon_words_literal(capsys: pytest.CaptureFixture[str]) -> None:
    common.console.print("signal 0:X:1 on TNC:/a", highlight=False)
    assert capsys.readouterr().out.strip() == "signal 0:X:1 on TNC:/a"
