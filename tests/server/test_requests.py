"""Remote-request rules, report programs and the configuration of both."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from opendnc.server.config.shop import ConfigError, parse_config
from opendnc.server.core.requests import RequestRule, RequestSettings, find_request, report_program
from opendnc.xmodem.haas import program_header

DEFAULT = RequestSettings()
CLI = [sys.executable, "-m", "opendnc.cli.main"]


@pytest.mark.parametrize(
    ("program", "names"),
    [
        (b"%\nO09999 (REQ O1234)\nM30\n%\n", ["O01234.nc"]),
        (b"%\r\nO09999\r\n(REQ 77)\r\nM30\r\n%\r\n", ["O00077.nc"]),
        (b"%\nO09999 (REQ O111 REQ O222)\nM30\n%\n", ["O00111.nc", "O00222.nc"]),
        (b"%\nO09999 (/REQ 111 /REQ 222)\nM30\n%\n", ["O00111.nc", "O00222.nc"]),
        (b"%\nO09999 (PRG=1234)\nM30\n%\n", ["O01234.nc"]),
        (b"%\nO09999 (req o5)\n%\n", ["O00005.nc"]),
        (b"%\nO01234 (BRACKET)\nG00 X0.\nM30\n%\n", None),
        # A request comment further down than the scanned lines is an ordinary program.
        (b"%\nO01\nG00\nG01\nG02\nG03\nG04\n(REQ O1234)\n%\n", None),
    ],
)
def test_default_rules(program: bytes, names: list[str] | None) -> None:
    assert find_request(program, DEFAULT) == names


def test_custom_rule_with_a_template() -> None:
    rule = RequestRule.make(r"\(SEND\s+(?P<part>[A-Z0-9_]+)\)", "{part}.H")
    settings = RequestSettings(rules=(rule,))
    assert find_request(b"%\nO9999 (SEND BRACKET_7)\n%\n", settings) == ["BRACKET_7.H"]
    assert find_request(b"%\nO9999 (REQ O1234)\n%\n", settings) is None


def test_report_program_is_a_valid_haas_program() -> None:
    text = report_program(9998, "request failed", ["O01234.nc not in library (v2)"])
    assert text == (
        b"%\r\nO09998 (OPENDNC REQUEST FAILED)\r\n(O01234.NC NOT IN LIBRARY V2)\r\nM30\r\n%\r\n"
    )
    header = program_header(text)
    assert header is not None
    assert header.number == 9998


@pytest.mark.parametrize(
    ("toml", "key"),
    [
        ("[requests]\ndelay = -1\n", "requests.delay"),
        ("[requests]\nreports = 'some'\n", "requests.reports"),
        ("[requests]\nreport_program = 0\n", "requests.report_program"),
        ("[requests]\ncolour = 'red'\n", "requests.colour"),
        ("[[requests.rules]]\npattern = '(unclosed'\ntemplate = 'x'\n", "requests.rules[0]"),
        ("[[requests.rules]]\npattern = 'A(?P<a>.)'\ntemplate = '{b}.nc'\n", "requests.rules[0]"),
        # A template names a program in the library: no folders, no field tricks.
        *(
            (f"[[requests.rules]]\npattern = 'S(?P<a>.)'\ntemplate = '{t}'\n", "requests.rules[0]")
            for t in ("../{a}.nc", "{a}/x.nc", "C:\\\\{a}", "{}.nc", "{a.real}", "{a!r}{", "{a:d}")
        ),
        ("[[machines]]\nname = 'm'\nkind = 'lsv2'\nhost = 'h'\nport = 'x'\n", "machines[0].port"),
        ("[[machines]]\nname = 'm'\nkind = 'fanuc'\n", "machines[0].kind"),
        ("[[machines]]\nname = '../m'\nkind = 'lsv2'\n", "machines[0].name"),
        ("[[machines]]\nname = 'm'\nkind = 'haas_serial'\n", "machines[0].serial"),
        (
            "[[machines]]\nname = 'm'\nkind = 'haas_serial'\nserial = '/dev/ttyS0'\n"
            "serial_profile = { baud = 12345 }\n",
            "machines[0].serial_profile.baud",
        ),
        ("[[machines]]\nname = 'a'\nkind = 'lsv2'\nhost = 'h'\n" * 2, "machines[1].name"),
        ("[server]\nbind = 'nowhere'\n", "server.bind"),
        ("[server]\ndatabase = 'mysql://x'\n", "server.database"),
        ("[library]\nwatch = 'sometimes'\n", "library.watch"),
        ("machines = 3\n", "machines"),
    ],
)
def test_bad_configuration_names_the_key(toml: str, key: str, tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as caught:
        parse_config(toml, base=tmp_path)
    assert caught.value.key == key
    assert str(caught.value).startswith(f"{key}: ")
    assert "\n" not in str(caught.value)


def test_malformed_toml_is_one_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"^not valid TOML: .*line 2"):
        parse_config("[server]\nbind = \n", base=tmp_path)


def test_relative_paths_are_taken_from_the_file(tmp_path: Path) -> None:
    config = parse_config(
        "[server]\ndatabase = 'sqlite:///db/shop.db'\n[library]\npath = 'progs'\n", base=tmp_path
    )
    assert config.server.database == f"sqlite:///{tmp_path / 'db' / 'shop.db'}"
    assert config.library.path == tmp_path / "progs"


def test_the_rule_tester_shows_the_rule_that_takes_a_request(tmp_path: Path) -> None:
    # CIMCO's test box, on the command line: type a request, see the rule and the names.
    config = tmp_path / "shop.toml"
    config.write_text(
        "[[requests.rules]]\npattern = '\\(SEND\\s+(?P<part>\\S+)\\)'\ntemplate = '{part}.H'\n"
        "[[requests.rules]]\npattern = '\\(REQ\\s+O?(?P<number>\\d+)\\)'\n"
        "template = 'O{number}.nc'\n"
    )

    def tester(program: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [*CLI, "requests", "test", "--json", "--config", str(config), program],
            capture_output=True,
            text=True,
            timeout=60,
        )

    second = tester("%\\nO9999 (REQ 12)\\n%")
    assert second.returncode == 0, second.stderr
    assert json.loads(second.stdout) == {
        "rule": 1,
        "pattern": "\\(REQ\\s+O?(?P<number>\\d+)\\)",
        "names": ["O00012.nc"],
        "refused": [],
    }
    first = json.loads(tester("%\\nO9999 (SEND BRACKET) (REQ 12)\\n%").stdout)
    assert (first["rule"], first["names"]) == (0, ["BRACKET.H"])
    sneaky = json.loads(tester("%\\nO9999 (SEND ../../etc/passwd)\\n%").stdout)
    assert sneaky["refused"] == ["../../etc/passwd.H"]
    plain = tester("%\\nO1234 (BRACKET)\\nM30\\n%")
    assert plain.returncode == 1
    assert json.loads(plain.stdout) is None


@pytest.mark.parametrize(
    ("toml", "first_words"),
    [
        ("[[machines]]\nname = 'm'\nkind = 'lsv2'\nhost = 'h'\nport = 'x'\n", "machines[0].port: "),
        ("[server]\nbind = \n", "not valid TOML: "),
    ],
)
def test_serve_with_a_bad_configuration_says_one_line(
    tmp_path: Path, toml: str, first_words: str
) -> None:
    config = tmp_path / "shop.toml"
    config.write_text(toml)
    proc = subprocess.run(
        [*CLI, "serve", "--config", str(config), "--db", f"sqlite:///{tmp_path / 'x.db'}"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 1
    # the file is named first: a shop may have several configurations
    assert proc.stderr.startswith(f"error: {config}: {first_words}"), proc.stderr
    assert proc.stderr.count("\n") == 1, proc.stderr
    assert not (tmp_path / "x.db").exists()  # nothing started, nothing written
