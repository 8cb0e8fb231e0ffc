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
