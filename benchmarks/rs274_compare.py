"""LinuxCNC's ``rs274`` beside our checker, on the same G-code files of our corpora (issue 33).

The method and the last figures: docs/check.md#beside-linuxcncs-rs274.

``rs274`` is LinuxCNC's standalone G-code interpreter (Debian package ``linuxcnc-uspace``;
measured with 2.9.0~pre1+git20230208.f1270d6ed7-1+deb12u2, Debian 12). Run with ``-g`` it
reads a whole program without a machine and prints the canonical commands it would send;
with ``-n 0`` it goes on after an error, so it reports every block it rejects: the message,
then the rejected block's text. It prints no line number, so the line is found here: the
file line holding that text, and where several lines hold it, the first one at which a run of
the file cut after that line gives the error (the interpreter reads from the top).

The tool table given to it (``-t``) holds tools T1-T99 with length 0 and diameter 0.2, so that
a tool change or ``G43 H n`` of a corpus program finds its tool, as on a machine set up for the
job (rs274's built-in table has only T1-T3). Nothing else of rs274 is changed: no INI file,
its default parameters, block delete off.

Which files: every G-code program of tests/data/nccheck (``*.nc``), tests/data/nccheck/corpus/
gcode (with ``defects/``) and the G-code programs of tests/data/corpus/real (MANIFEST.toml), but
those listed in :data:`EXCLUDED`. We ran rs274 on each file; those excluded are the ones written
in a language LinuxCNC does not share (its dialect, not a fault of the program): Fanuc macro B
control flow (``IF``/``WHILE``/``GOTO``), arithmetic without brackets (``#1 = #2 / #3``), ``G65``
macro calls, Haas ``M97``, Haas ``G187``, Fanuc ``G54.1``/``G05.1``, lathe programs in G-code
system A (``U``/``W`` incremental words, ``T0101``, ``G50 S``, ``G71 P Q``), the machine
builder's M codes, ``:`` program numbers, a comment before the leading ``%``. Each row of the
excluded table still shows what rs274 said about the file, so the choice can be checked. Heidenhain
programs (Klartext ``.h``, ISO ``.i``) are not G-code rs274 reads; they are not listed.

Our side: :func:`opendnc.nccheck.check_file` with the control the corpus names for the file (the
same one its tests use: ``fanuc-mill`` for a Fanuc tap, ``haas-mill`` for a Haas one), else the
guessed one (the Haas/Fanuc ``mill`` union). What the corpus says of each file (correct, or its
defect lines) is read from the tests' own tables (tests/unit/nccheck/test_corpus.py,
test_gcode_corpus.py, tests/data/corpus/real/MANIFEST.toml), not written again here.

An rs274 error is *caught* by us when we give an error on its line; where we do not, an error of
ours (or the warning the corpus expects there) on one of the corpus's defect lines of that file,
at or before rs274's line and not yet paired with another rs274 error, also counts: rs274 may
meet a defect later than the corpus places it (a missing sub-program at the end of the file).

    .venv/bin/python benchmarks/rs274_compare.py
    .venv/bin/python benchmarks/rs274_compare.py --rs274 /opt/linuxcnc/bin/rs274

Exit status: 0 when we catch everything rs274 catches on the defect files; 1 when rs274 catches
an error there that we miss; 2 when rs274 cannot be run.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import tomllib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the corpus tables are the tests' own

from tests.unit.nccheck import test_corpus, test_gcode_corpus  # noqa: E402

from opendnc.nccheck import Budget, MachineLimits, Severity, check_file  # noqa: E402

DATA = ROOT / "tests" / "data"
PACKAGE = "linuxcnc-uspace"
BUDGET = Budget(blocks=200_000)
TIMEOUT_S = 60.0
MAX_ERRORS = 500

_MACRO_B = "Fanuc macro B control flow, which LinuxCNC writes with O-words"
_BARE_MATH = "macro arithmetic without brackets (LinuxCNC needs [..] around an expression)"
_LATHE = "lathe, G-code system A: U/W incremental, T0101, G50 S (LinuxCNC: other meanings)"

EXCLUDED: dict[str, str] = {
    "nccheck/clean_fanuc_macro.nc": "G65 macro call, Haas M97 local sub-program, WHILE/DO",
    "nccheck/division_by_zero.nc": _BARE_MATH,
    "nccheck/endless_loop.nc": f"{_BARE_MATH}; GOTO",
    "nccheck/goto_missing.nc": f"IF [..] GOTO: {_MACRO_B}",
    "nccheck/while_without_end.nc": f"WHILE/DO: {_MACRO_B}; {_BARE_MATH}",
    "nccheck/corpus/gcode/fanuc_lathe.nc": _LATHE,
    "nccheck/corpus/gcode/fanuc_lathe_builder_m_codes.nc": f"{_LATHE}; builder M codes",
    "nccheck/corpus/gcode/haas_lathe.nc": _LATHE,
    "nccheck/corpus/gcode/fanuc_mill_builder_m_codes.nc": (
        "the machine builder's M40/M41 (LinuxCNC's own user M codes are M100-M199)"
    ),
    "nccheck/corpus/gcode/fusion_haas_mill.nc": "Haas G187 (smoothness), unknown to LinuxCNC",
    "nccheck/corpus/gcode/mastercam_fanuc_mill.nc": (
        "Fanuc G54.1 P1 and G05.1 Q1 (LinuxCNC's G5.1 is a quadratic spline, needing I/J)"
    ),
    "nccheck/corpus/gcode/renishaw_probing.nc": (
        "comments before the leading % (LinuxCNC takes % on the first line only); G65 calls"
    ),
    "nccheck/corpus/gcode/defects/alarm_reached.nc": f"IF [..] THEN #3000: {_MACRO_B}",
    "nccheck/corpus/gcode/defects/comment_before_percent.nc": (
        "a comment before the leading % (LinuxCNC takes % on the first line only)"
    ),
    "nccheck/corpus/gcode/defects/division_by_unset.nc": _BARE_MATH,
    "nccheck/corpus/gcode/defects/lathe_contour_missing.nc": _LATHE,
    "nccheck/corpus/gcode/defects/lathe_feed_stopped.nc": _LATHE,
    "nccheck/corpus/gcode/defects/m97_without_m99.nc": "Haas M97 local sub-program",
    "nccheck/corpus/gcode/defects/two_faults.nc": _BARE_MATH,
    "corpus/real/fanuc-lathe/gcodeworkshop/0100.nc": f"':0100' program number; {_LATHE}",
    "corpus/real/fanuc-mill/gcodeworkshop/FANUC0M.nc": (
        "':0097' program number; the machine builder's M20"
    ),
}
"""File (under tests/data) -> why rs274 is not run beside us on it."""


@dataclass(frozen=True)
class Expected:
    """What the corpus says of one file."""

    path: Path
    dialect: str | None
    """The control the corpus checks it with (None: guessed)."""
    defects: dict[int, Severity] = field(default_factory=dict)
    """Defect line -> the severity the corpus expects there; empty: a correct program."""

    @property
    def key(self) -> str:
        return self.path.relative_to(DATA).as_posix()


def corpus() -> list[Expected]:
    """Every G-code file of our corpora, with what its tests expect of it."""
    found: list[Expected] = []
    # tests/data/nccheck: a file not in test_corpus.DEFECTS is correct without a machine
    own = {name: (line, severity) for name, line, _b, severity, _w in test_corpus.DEFECTS}
    for path in sorted((DATA / "nccheck").glob("*.nc")):
        dialect = test_corpus.DEFECT_DIALECT.get(path.name)
        if path.name in own:
            line, severity = own[path.name]
            found.append(Expected(path, dialect, {line: severity}))
        else:
            found.append(Expected(path, dialect))
    gcode = DATA / "nccheck" / "corpus" / "gcode"
    for name, dialect in sorted(test_gcode_corpus.CLEAN.items()):
        found.append(Expected(gcode / name, dialect))
    for name, lines in sorted(test_gcode_corpus.DEFECTS.items()):
        dialect = test_gcode_corpus.DEFECT_CONTROL.get(name)
        defects = {line: Severity.ERROR for line, _words in lines}
        found.append(Expected(gcode / "defects" / name, dialect, defects))
    real = DATA / "corpus" / "real"
    manifest = tomllib.loads((real / "MANIFEST.toml").read_text("utf-8"))
    for item in manifest["file"]:
        if item["control"] == "heidenhain":
            continue
        defects = {line: Severity.ERROR for d in item.get("defect", []) for line in d["lines"]}
        found.append(Expected(real / item["path"], item["control"], defects))
    return found


@dataclass(frozen=True)
class Rs274Error:
    line: int | None
    message: str


class Rs274:
    """Runs LinuxCNC's rs274 on a file (in a scratch folder, with a T1-T99 tool table)."""

    def __init__(self, exe: str, scratch: Path) -> None:
        self.exe = exe
        self.scratch = scratch
        self.tools = scratch / "tools.tbl"
        rows = [f"T{n} P{n} Z0 D0.2 ;corpus tool {n}" for n in range(1, 100)]
        self.tools.write_text("\n".join(rows) + "\n", "ascii")

    def version(self) -> str:
        """The Debian package and version rs274 comes from (it prints no version itself)."""
        try:
            owner = subprocess.run(
                ["dpkg", "-S", os.path.realpath(self.exe)],
                capture_output=True, text=True, timeout=TIMEOUT_S, check=False,
            )  # fmt: skip
            package = owner.stdout.partition(":")[0].strip()
            if owner.returncode != 0 or not package:
                return "version unknown (not from a Debian package)"
            done = subprocess.run(
                ["dpkg-query", "-W", "-f", "${Version}", package],
                capture_output=True, text=True, timeout=TIMEOUT_S, check=False,
            )  # fmt: skip
        except OSError:
            return "version unknown (no dpkg)"
        return f"{package} {done.stdout.strip()}"

    def raw(self, path: Path) -> list[tuple[str, str]]:
        """rs274's errors on ``path``: (message, the rejected block as it printed it)."""
        # read as it prints: in its go-on mode (-n 0) a file with neither an end nor a closing
        # % repeats "File ended with no percent sign ..." for ever, so the second one ends it
        process = subprocess.Popen(
            [self.exe, "-t", str(self.tools), "-n", "0", "-g", str(path)],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            errors="replace",
            cwd=self.scratch,
        )
        assert process.stderr is not None
        timer = threading.Timer(TIMEOUT_S, process.kill)
        timer.start()
        pairs: list[tuple[str, str]] = []
        try:
            rows = (r.rstrip("\n") for r in process.stderr if r.strip() not in ("", "executing"))
            for message in rows:
                pair = (message, next(rows, ""))
                if pair in pairs[-1:] and message.startswith("File ended"):
                    break
                pairs.append(pair)
                if len(pairs) >= MAX_ERRORS:
                    break
        finally:
            process.kill()
            process.wait()
            timer.cancel()
        if process.returncode not in (0, 1, -signal.SIGKILL) and not pairs:
            pairs.append((f"rs274 ended with status {process.returncode}", ""))
        return pairs

    def errors(self, path: Path) -> list[Rs274Error]:
        """rs274's errors on ``path``, each with the file line it rejected."""
        lines = path.read_text("latin-1").splitlines()
        pairs = self.raw(path)
        seen: Counter[tuple[str, str]] = Counter()
        out = []
        for message, block in pairs:
            nth = seen[(message, block)]
            seen[(message, block)] += 1
            out.append(Rs274Error(self._line(path, lines, message, block, nth), message))
        return out

    def _line(self, path: Path, lines: list[str], message: str, block: str, nth: int) -> int | None:
        text = block.strip()
        if not text:
            return None
        # rs274 prints a long block cut short: a prefix of the file's line
        candidates = [
            i
            for i, row in enumerate(lines, 1)
            if row.strip() == text or (len(text) >= 200 and row.strip().startswith(text))
        ]
        if len(candidates) <= 1:
            return candidates[0] if candidates else None
        # several lines hold that block: the first cut of the file that gives the error (nth+1
        # times) ends at it
        for line in candidates:
            cut = self.scratch / f"cut{path.suffix}"
            cut.write_text("\n".join(lines[:line]) + "\n", "latin-1")
            if self.raw(cut).count((message, block)) > nth:
                return line
        return None


@dataclass
class Row:
    expected: Expected
    rs274: list[Rs274Error]
    ours: list[tuple[int, Severity, str]]
    """Our errors, and our problems of the severity the corpus expects on its lines."""
    missed: list[Rs274Error]


def ours(expected: Expected) -> list[tuple[int, Severity, str]]:
    machine = MachineLimits(dialect=expected.dialect) if expected.dialect else None
    result = check_file(expected.path, name=expected.path.name, machine=machine, budget=BUDGET)
    return [
        (p.line, p.severity, p.message)
        for p in result.problems
        if p.severity is Severity.ERROR or p.severity is expected.defects.get(p.line)
    ]


def missed_by_us(
    expected: Expected, theirs: list[Rs274Error], mine: list[tuple[int, Severity, str]]
) -> list[Rs274Error]:
    """The rs274 errors we do not catch (on its line, or paired with a corpus defect line)."""
    our_lines = {line for line, _s, _m in mine}
    spare = sorted(line for line in expected.defects if line in our_lines)
    left = []
    for error in theirs:
        if error.line in our_lines:
            if error.line in spare:
                spare.remove(error.line)
        else:
            left.append(error)
    missed = []
    for error in left:
        # it reads from the top, so it meets a defect at its block or later (at the end of
        # the file: a sub-program it did not find), never before
        before = [line for line in spare if error.line is not None and line <= error.line]
        if before:
            spare.remove(before[0])
        else:
            missed.append(error)
    return missed


def _name(key: str) -> str:
    return key.replace("nccheck/corpus/gcode/", "gcode/").replace("corpus/real/", "real/")


def _short(text: str, width: int) -> str:
    return text if len(text) <= width else text[: width - 3] + "..."


def _verdict(errors: list[tuple[int | None, str]], width: int = 44) -> str:
    if not errors:
        return "ok"
    first_line, first = errors[0]
    more = f" +{len(errors) - 1}" if len(errors) > 1 else ""
    return _short(f"{first_line or '?'}: {first}", width - len(more)) + more


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--rs274", default="", help="the rs274 binary (default: on PATH)")
    args = parser.parse_args()
    exe = args.rs274 or shutil.which("rs274") or ""
    missing = f"rs274 not found: install LinuxCNC's interpreter (apt-get install {PACKAGE})"
    if not exe or not os.access(exe, os.X_OK):
        print(missing)
        return 2
    entries = corpus()
    unknown = set(EXCLUDED) - {e.key for e in entries}
    if unknown:
        print(f"EXCLUDED names files that are not in the corpus: {sorted(unknown)}")
        return 2
    with tempfile.TemporaryDirectory(prefix="rs274-") as scratch:
        rs274 = Rs274(exe, Path(scratch))
        # a program with nothing wrong must pass: else rs274 does not run here (libraries)
        probe = Path(scratch) / "probe.ngc"
        probe.write_text("%\nG21 G90\nG0 X1 Y1\nM2\n%\n", "ascii")
        try:
            broken = rs274.raw(probe)
        except OSError as exc:
            broken = [(str(exc), "")]
        if broken:
            print(f"{missing}: {exe} does not run ({broken[0][0]})")
            return 2
        version = rs274.version()
        rows: list[Row] = []
        skipped: list[tuple[Expected, list[Rs274Error]]] = []
        for entry in entries:
            theirs = rs274.errors(entry.path)
            if entry.key in EXCLUDED:
                skipped.append((entry, theirs))
                continue
            mine = ours(entry)
            missed = missed_by_us(entry, theirs, mine) if entry.defects else []
            rows.append(Row(entry, theirs, mine, missed))
    print(f"rs274 of {version} ({exe}) beside opendnc's checker\n")
    print(f"{'file':40} {'corpus':7} {'rs274: line: error':44} {'ours: line: error':44} dialect")
    for row in rows:
        status = "defect" if row.expected.defects else "correct"
        theirs_text = _verdict([(e.line, e.message) for e in row.rs274])
        mine_text = _verdict([(line, message) for line, _s, message in row.ours])
        dialect = row.expected.dialect or "guessed"
        name = _name(row.expected.key)
        print(f"{name:40} {status:7} {theirs_text:44} {mine_text:44} {dialect}")
        for error in row.missed:
            print(f"  MISSED by us: rs274 line {error.line or '?'}: {error.message}")
    print(f"\nnot run beside us ({len(skipped)} files, in a dialect LinuxCNC does not read):")
    for entry, theirs in skipped:
        lines = ", ".join(str(e.line or "?") for e in theirs) or "none"
        print(f"  {_name(entry.key):40} {EXCLUDED[entry.key]}")
        print(
            f"  {'':40} rs274 rejects lines {lines}; first: {theirs[0].message if theirs else '-'}"
        )
    defects = [r for r in rows if r.expected.defects]
    correct = [r for r in rows if not r.expected.defects]
    listed = sum(len(r.expected.defects) for r in defects)
    ours_hit = sum(1 for r in defects for line in r.expected.defects if line in _lines(r.ours))
    theirs_hit = sum(
        1 for r in defects for line in r.expected.defects if line in {e.line for e in r.rs274}
    )
    our_errors = sum(1 for r in rows for _l, severity, _m in r.ours if severity is Severity.ERROR)
    our_warnings = sum(len(r.ours) for r in rows) - our_errors
    misses = sum(len(r.missed) for r in rows)
    print(
        f"\nsummary: {len(rows)} files ({len(defects)} defect, {len(correct)} correct), "
        f"{len(skipped)} not run beside us"
    )
    print(
        f"  errors: rs274 {sum(len(r.rs274) for r in rows)}, ours {our_errors} "
        f"(and {our_warnings} warning(s) the corpus expects)"
    )
    print(
        f"  defect lines of the corpus flagged: ours {ours_hit}/{listed}, "
        f"rs274 {theirs_hit}/{listed}"
    )
    print(f"  caught by rs274 and missed by us: {misses}")
    print(
        f"  false alarms on correct files: rs274 {sum(len(r.rs274) for r in correct)} "
        f"({_files(correct, rs274=True)}), ours {sum(len(r.ours) for r in correct)} "
        f"({_files(correct, rs274=False)})"
    )
    return 1 if misses else 0


def _lines(found: list[tuple[int, Severity, str]]) -> set[int]:
    return {line for line, _s, _m in found}


def _files(rows: list[Row], *, rs274: bool) -> str:
    names = [Path(r.expected.key).name for r in rows if (r.rs274 if rs274 else r.ours)]
    return ", ".join(names) or "none"


if __name__ == "__main__":
    sys.exit(main())
