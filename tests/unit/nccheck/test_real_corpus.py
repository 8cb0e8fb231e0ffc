"""The checker on real programs from public repositories (tests/data/corpus/real).

``MANIFEST.toml`` there names each file's source, licence and control, and whether it is
correct or which of its lines are real defects. A correct program must check with no error
(each false error would block its release on the server); every listed defect line must get
its error, and no error may stand elsewhere. The last test prints the tally per control.
"""

from __future__ import annotations

import tomllib
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import pytest

from opendnc.nccheck import Budget, CheckResult, MachineLimits, check_text

REAL = Path(__file__).resolve().parents[2] / "data" / "corpus" / "real"
BUDGET = Budget(blocks=200_000)


@dataclass(frozen=True)
class Entry:
    path: str
    repository: str
    licence: str
    control: str
    status: str
    defects: dict[int, str]  # file line -> words its error must hold


def _entries() -> list[Entry]:
    manifest = tomllib.loads((REAL / "MANIFEST.toml").read_text("utf-8"))
    entries = []
    for item in manifest["file"]:
        defects = {line: d["words"] for d in item.get("defect", []) for line in d["lines"]}
        entries.append(
            Entry(
                item["path"],
                item["repository"],
                item["licence"],
                item["control"],
                item["status"],
                defects,
            )
        )
    return entries


ENTRIES = _entries()


_RESULTS: dict[tuple[str, bool], CheckResult] = {}


def check(entry: Entry, named: bool = True) -> CheckResult:
    """The check of one file, run once per test session (the tally reuses it: cheap)."""
    key = (entry.path, named)
    if key not in _RESULTS:
        # G-code is checked with its control named (a Fanuc lathe is no mill); Klartext
        # names its control itself
        dialect = entry.control if named and entry.control != "heidenhain" else None
        machine = MachineLimits(dialect=dialect) if dialect else None
        text = (REAL / entry.path).read_text("utf-8")
        _RESULTS[key] = check_text(text, name=Path(entry.path).name, machine=machine, budget=BUDGET)
    return _RESULTS[key]


def test_the_manifest_names_every_file_once() -> None:
    on_disk = {
        str(p.relative_to(REAL)) for p in REAL.rglob("*") if p.is_file() and p.suffix != ".toml"
    }
    listed = [e.path for e in ENTRIES]
    assert sorted(listed) == sorted(on_disk)
    assert len(set(listed)) == len(listed)
    for entry in ENTRIES:
        assert entry.repository
        assert entry.licence
        assert entry.status in ("correct", "defect")
        assert (entry.status == "defect") == bool(entry.defects)


@pytest.mark.parametrize("entry", ENTRIES, ids=[e.path for e in ENTRIES])
def test_a_real_program_gives_exactly_its_real_defects(entry: Entry) -> None:
    result = check(entry)
    errors = [(p.line, p.message) for p in result.errors]
    false = [(line, message) for line, message in errors if line not in entry.defects]
    assert false == []
    for line, words in entry.defects.items():
        assert any(at == line and words in message for at, message in errors), (line, words)
    if entry.status == "correct" and entry.control != "heidenhain":
        # a guessed control must not cry wolf on a correct program either
        assert check(entry, named=False).errors == ()


def test_the_tally_per_control(capsys: pytest.CaptureFixture[str]) -> None:
    files: Counter[str] = Counter()
    repos: dict[str, set[str]] = {}
    false: Counter[str] = Counter()
    caught: Counter[str] = Counter()
    listed: Counter[str] = Counter()
    for entry in ENTRIES:
        files[entry.control] += 1
        repos.setdefault(entry.control, set()).add(entry.repository)
        lines = {p.line for p in check(entry).errors}
        false[entry.control] += len(lines - set(entry.defects))
        caught[entry.control] += len(lines & set(entry.defects))
        listed[entry.control] += len(entry.defects)
    with capsys.disabled():
        print("\nreal corpus (files, repositories, defect lines caught/listed, false error lines):")
        for control in sorted(files):
            where = f"{files[control]} files, {len(repos[control])} repositories"
            counts = f"{caught[control]}/{listed[control]} caught, {false[control]} false"
            print(f"  {control}: {where}, {counts}")
    assert sum(false.values()) == 0
    assert caught == listed
