"""The repository's protocol reference: links resolve, and code cites only what exists in docs/."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
DOCS = REPO / "docs"
CODE_DIRS = ("src", "tests", "benchmarks")
# the web pages' scripts, styles and templates cite docs as well
CODE_SUFFIXES = (".py", ".js", ".css", ".html")

_LINK = re.compile(r"\]\(([^)#\s]+)?(?:#([^)\s]+))?\)")
_CITE = re.compile(r"docs/([\w-]+\.md)(?:#([\w-]+))?")
# Documents that live outside the repository, and internal shorthand, must not be cited.
_FOREIGN = re.compile(
    r"lsv2-protocol\.md|haas-protocols\.md|peers-and-limits\.md|\bseed ?0\d\d\b|§|\bB[12]'s\b"
    r"|\(reference\b|of the reference\b|\breference §",
    re.IGNORECASE,
)


def anchors(page: Path) -> set[str]:
    """GitHub-style anchors of every heading of ``page``."""
    out = set()
    for line in page.read_text("utf-8").splitlines():
        if line.startswith("#"):
            title = line.lstrip("#").strip().lower()
            slug = re.sub(r"[^\w\- ]", "", title).replace(" ", "-")
            out.add(slug)
    return out


def pages() -> list[Path]:
    return sorted(DOCS.rglob("*.md"))


def test_docs_exist() -> None:
    names = {p.name for p in pages()}
    assert {"README.md", "lsv2.md", "haas.md", "xmodem.md", "tnc-profiles.md"} <= names


@pytest.mark.parametrize("page", pages(), ids=lambda p: p.name)
def test_links_in_docs_resolve(page: Path) -> None:
    for target, anchor in _LINK.findall(page.read_text("utf-8")):
        if target.startswith(("http://", "https://")):
            continue
        path = (page.parent / target) if target else page
        assert path.exists(), f"{page.name}: broken link {target}"
        if anchor and path.suffix == ".md":
            assert anchor in anchors(path), f"{page.name}: no section #{anchor} in {target}"


def code_files() -> list[Path]:
    files = []
    for top in CODE_DIRS:
        files += [
            p
            for p in (REPO / top).rglob("*")
            if p.suffix in CODE_SUFFIXES and p.is_file() and p.name != "test_docs.py"
        ]
    return sorted(files)


def test_code_cites_existing_sections() -> None:
    missing = []
    for path in code_files():
        for number, line in enumerate(path.read_text("utf-8").splitlines(), 1):
            for name, anchor in _CITE.findall(line):
                page = DOCS / name
                if not page.exists() or (anchor and anchor not in anchors(page)):
                    missing.append(f"{path.relative_to(REPO)}:{number}: docs/{name}#{anchor}")
    assert not missing


def test_code_cites_nothing_outside_the_repository() -> None:
    foreign = [
        f"{path.relative_to(REPO)}:{number}: {line.strip()}"
        for path in code_files()
        for number, line in enumerate(path.read_text("utf-8").splitlines(), 1)
        if _FOREIGN.search(line)
    ]
    assert not foreign
