"""The utilization package imports only what its docstring allows: never ``web/`` (the pages
import it) and never a module of API routes other than the shared pieces."""

from __future__ import annotations

import ast
from pathlib import Path

import opendnc.server.utilization as package

PACKAGE = Path(package.__file__).parent
# the modules of API routes: they sit above utilization, which must not reach up to them
ROUTE_MODULES = {
    "opendnc.server.http.api",
    "opendnc.server.http.dprnt",
    "opendnc.server.http.alerts",
}


def imported(path: Path) -> set[str]:
    """Every module ``path`` imports, at the top or inside a function, as a dotted name
    (``from opendnc.server import api`` is ``opendnc.server.http.api``)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def forbidden(name: str) -> bool:
    """Whether the utilization package may not import ``name``."""
    return (
        name == "opendnc.server.web"
        or name.startswith("opendnc.server.web.")
        or name in ROUTE_MODULES
        or any(name.startswith(m + ".") for m in ROUTE_MODULES)
    )


def test_the_package_reaches_neither_pages_nor_api_routes() -> None:
    modules = sorted(PACKAGE.glob("*.py"))
    assert {p.stem for p in modules} >= {"collect", "days", "sums", "answer", "component"}
    offending = {
        p.name: sorted(n for n in imported(p) if forbidden(n))
        for p in modules
        if any(forbidden(n) for n in imported(p))
    }
    assert offending == {}


def test_the_rule_sees_every_form_of_import(tmp_path: Path) -> None:
    # the check itself: each way of writing the forbidden import is caught
    for line in (
        "from opendnc.server import api",
        "from opendnc.server.http.api import ERRORS",
        "import opendnc.server.web.views",
        "def f():\n    from opendnc.server.web import render",
    ):
        source = tmp_path / "m.py"
        source.write_text(line + "\n", encoding="utf-8")
        assert any(forbidden(n) for n in imported(source)), line
    source.write_text("from opendnc.server.http.shared import ERRORS\n", encoding="utf-8")
    assert not any(forbidden(n) for n in imported(source))
