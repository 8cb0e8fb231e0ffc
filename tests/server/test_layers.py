"""The server's packages stand in layers: each imports only its own and the packages under it
(docs/server.md#the-servers-packages). Every import counts, at the top, inside a function or
only for type checking: an import upward is how circles start."""

from __future__ import annotations

import ast
from pathlib import Path

import opendnc.server as server

SERVER = Path(server.__file__).parent

LAYERS = (
    "core",
    "store",
    "kinds",
    "config",
    "library",
    "machines",
    "jobs",
    "netshare",
    "utilization",
    "access",
    "utilization",
    "actions",
    "fleet",
    "outputs",
    "cluster",
    "alerts",
    "http",
    "web",
    "reports",
    "app",  # app.py: builds the server from all of them
)
"""Lowest first: a package may import those before it, never one after it."""

RANK = {name: i for i, name in enumerate(LAYERS)}


def imported(source: str) -> set[str]:
    """Every module ``source`` imports, as a dotted name (``from opendnc.server import
    actions`` gives ``opendnc.server`` and ``opendnc.server.actions``)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def layer_of(module: str) -> str | None:
    """The layer of ``opendnc.server.X...`` (None: outside the server's packages)."""
    parts = module.split(".")
    if parts[:2] != ["opendnc", "server"] or len(parts) < 3:
        return None
    return parts[2] if parts[2] in RANK else None


def upward(layer: str, source: str) -> list[str]:
    """The imports in ``source`` (of ``layer``) that reach a higher layer."""
    return sorted(
        name
        for name in imported(source)
        if (other := layer_of(name)) is not None and RANK[other] > RANK[layer]
    )


def test_every_package_is_a_layer_and_says_what_it_may_import() -> None:
    packages = {p.parent.name for p in SERVER.glob("*/__init__.py")}
    assert packages == set(LAYERS) - {"app"}, "a package of the server not in LAYERS"
    for name in packages:
        doc = ast.get_docstring(ast.parse((SERVER / name / "__init__.py").read_text()))
        assert doc, f"server/{name}/__init__.py: a docstring"
        assert "import" in doc, f"server/{name}/__init__.py: say what it may import"
    modules = {p.stem for p in SERVER.glob("*.py")} - {"__init__"}
    assert modules == {"app"}, f"modules outside the packages: {sorted(modules - {'app'})}"


def test_no_package_imports_upward() -> None:
    offending: dict[str, list[str]] = {}
    for path in sorted(SERVER.rglob("*.py")):
        if "migrations" in path.parts:
            continue
        rel = path.relative_to(SERVER)
        layer = rel.parts[0] if len(rel.parts) > 1 else rel.stem
        if layer == "__init__":
            continue
        found = upward(layer, path.read_text(encoding="utf-8"))
        if found:
            offending[str(rel)] = found
    assert offending == {}


def test_the_rule_sees_every_form_of_import() -> None:
    # the check itself, on the machines layer reaching up to the jobs layer
    for line in (
        "from opendnc.server import jobs",
        "from opendnc.server.jobs.queue import enqueue",
        "import opendnc.server.jobs.runner",
        "def f():\n    from opendnc.server.jobs import runner",
        "if TYPE_CHECKING:\n    from opendnc.server.web import render",
    ):
        assert upward("machines", line + "\n"), line
    assert upward("machines", "from opendnc.server.library import versions\n") == []
    assert upward("machines", "from opendnc.server.machines.state import MachineState\n") == []


ROUTE_MODULES = {
    "opendnc.server.http.api",
    "opendnc.server.http.dprnt",
    "opendnc.server.http.utilization",
    "opendnc.server.http.alerts",
}
"""The JSON API's modules of routes: the pages call the actions, never these."""

STORAGE = ("sqlalchemy", "opendnc.server.store.models")
"""The database itself: a page or a route reads and writes through the actions."""

NEEDS_STORAGE = {
    "http/deps.py": "the Database component holds the engine and the session factories",
    "http/sessions.py": "the request's session and its after-commit hook",
    "http/edge.py": "tells a database outage (sqlalchemy.exc) from the route's own error",
    "http/downloads.py": "streams a blob piece by piece as the client reads it",
}
"""The modules of ``http/`` that touch the storage, and why; ``web/`` has none."""


def _reaches(name: str, targets: tuple[str, ...] | set[str]) -> bool:
    return any(name == t or name.startswith(t + ".") for t in targets)


def storage_imports(source: str) -> list[str]:
    """The imports in ``source`` of sqlalchemy or of the tables."""
    return sorted(n for n in imported(source) if _reaches(n, STORAGE))


def route_imports(source: str) -> list[str]:
    """The imports in ``source`` of a module of the API's routes."""
    return sorted(n for n in imported(source) if _reaches(n, ROUTE_MODULES))


def test_pages_and_routes_read_through_the_actions() -> None:
    storage: dict[str, list[str]] = {}
    routes: dict[str, list[str]] = {}
    for layer in ("web", "http"):
        for path in sorted((SERVER / layer).rglob("*.py")):
            rel = str(path.relative_to(SERVER))
            source = path.read_text(encoding="utf-8")
            if (found := storage_imports(source)) and rel not in NEEDS_STORAGE:
                storage[rel] = found
            if layer == "web" and (found := route_imports(source)):
                routes[rel] = found
    assert storage == {}, "SQL or tables outside the actions: read through an action"
    assert routes == {}, "a page calls a module of the API's routes: call the action"
    for rel in NEEDS_STORAGE:
        assert storage_imports((SERVER / rel).read_text(encoding="utf-8")), f"{rel}: not needed"


def test_the_read_rule_sees_sql_and_routes() -> None:
    for line in (
        "from sqlalchemy import select",
        "from sqlalchemy.orm import Session",
        "import sqlalchemy",
        "def f():\n    from opendnc.server.store.models import Job",
        "if TYPE_CHECKING:\n    from opendnc.server.store import models",
    ):
        assert storage_imports(line + "\n"), line
    assert storage_imports("from opendnc.server.store.health import x\n") == []
    assert route_imports("from opendnc.server.http import dprnt\n")
    assert route_imports("from opendnc.server.http.api import error_response\n")
    assert route_imports("from opendnc.server.http.deps import database\n") == []
