"""A machine kind is one package and one registry line: a kind defined here, in the test,
registered at run time, runs a real send through the server's job path; and the generic
server code names no concrete kind (docs/server.md#adding-a-machine-kind).

The kind ("drop") is a control that takes programs as files in a folder: its own schema
(``drop``, the folder), its own parser, a connector that writes each load there, its own
label. Nothing in ``src`` knows it.
"""

from __future__ import annotations

import ast
import hashlib
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, ClassVar

import pytest

from tests.peers import require_module

httpx = require_module("httpx")
require_module("jinja2")
require_module("uvicorn")

from opendnc.errors import ControlRefused, InputError  # noqa: E402
from opendnc.server.access import auth  # noqa: E402
from opendnc.server.app import build  # noqa: E402
from opendnc.server.config.shop import ConfigError, parse_config  # noqa: E402
from opendnc.server.core.configkeys import get_key  # noqa: E402
from opendnc.server.core.status import MachineStatus, Progress  # noqa: E402
from opendnc.server.kinds.base import (  # noqa: E402
    Capabilities,
    ConnectorHooks,
    KindSpec,
    MachineBase,
    schema_keys,
)
from opendnc.server.kinds.connector import NetworkOnly  # noqa: E402
from opendnc.server.kinds.registry import KINDS, register  # noqa: E402
from opendnc.server.library import versions as library  # noqa: E402
from opendnc.server.store.models import Role  # noqa: E402
from opendnc.server.web import session as web_session  # noqa: E402
from tests.server.harness import auth as bearer  # noqa: E402
from tests.server.harness import wait_for, wait_jobs  # noqa: E402
from tests.server.serving import serving  # noqa: E402

PROGRAM = b"%\nO01234 (DROPPED)\nG00 G90 X0. Y0.\nM30\n%\n"
LABEL = "Folder drop · test kind"
SERVER = Path(__file__).parents[2] / "src" / "opendnc" / "server"


@dataclass(frozen=True, kw_only=True)
class DropMachine(MachineBase):
    """A control that takes programs as files in a folder."""

    kind: ClassVar[str] = "drop"
    drop: str  # the folder the control reads


def _parse(raw: dict[str, Any], prefix: str, common: dict[str, Any]) -> DropMachine:
    drop = get_key(raw, prefix, "drop", str, "")
    if not drop:
        raise ConfigError(f"{prefix}.drop", "a drop machine needs its folder")
    return DropMachine(**common, drop=drop)


class DropConnector(NetworkOnly):
    """Writes each load into the machine's folder; its status is the folder being there."""

    def __init__(self, config: DropMachine) -> None:
        self.config = config
        self.folder = Path(config.drop)

    async def connect(self) -> None:
        if not self.folder.is_dir():
            raise ControlRefused(f"{self.folder}: no such folder")

    async def close(self) -> None:
        return None

    async def status(self) -> MachineStatus:
        return MachineStatus(at=datetime.now(UTC), available=True, execution="READY")

    async def send(self, name: str, data: bytes, progress: Progress) -> None:
        part = self.folder / f".{name}.part"
        part.write_bytes(data)
        part.replace(self.folder / name)
        progress(len(data), len(data))

    async def verify(self, name: str, data: bytes) -> bool | None:
        path = self.folder / name
        return path.is_file() and path.read_bytes() == data

    async def fetch(self, path: str) -> bytes:
        raise ControlRefused("a drop folder is not browsed")

    async def delete(self, path: str) -> None:
        raise ControlRefused("a drop folder is not browsed")

    async def backup(self, path: str, target: Path) -> dict[str, int]:
        return {"copied": 0, "unchanged": 0, "failed": 0}


def _connector(config: DropMachine, hooks: ConnectorHooks) -> DropConnector:
    return DropConnector(config)


SPEC = KindSpec(
    kind="drop",
    label=LABEL,
    schema=DropMachine,
    keys=schema_keys(DropMachine),
    parse=_parse,
    connector=_connector,
    capabilities=lambda config: Capabilities(status_fields=frozenset({"execution"})),
)


@pytest.fixture
def drop_kind() -> Iterator[KindSpec[DropMachine]]:
    """The test's kind, in the table for this test only."""
    register(SPEC)
    try:
        yield SPEC
    finally:
        KINDS.pop(SPEC.kind, None)


def _config(tmp_path: Path, drop: Path) -> str:
    return (
        f'[library]\npath = "{tmp_path / "lib"}"\ninbox = "{tmp_path / "inbox"}"\n'
        f'archive = "{tmp_path / "archive"}"\n\n'
        f'[[machines]]\nname = "dropper"\nkind = "drop"\ndrop = "{drop}"\npoll_interval = 0.2\n'
    )


def test_a_kind_defined_in_a_test_runs_a_send_through_the_job_path(
    tmp_path: Path, drop_kind: KindSpec[DropMachine]
) -> None:
    drop = tmp_path / "drop"
    drop.mkdir()
    config = parse_config(_config(tmp_path, drop), base=tmp_path)
    (machine,) = config.machines
    assert isinstance(machine, DropMachine)
    assert machine.drop == str(drop)
    # the real connector, made through the registry: no connector_factory
    server = build(config, database=f"sqlite:///{tmp_path / 'db.sqlite'}")
    with server.sessions.begin() as session:
        library.add_version(session, "O01234.nc", PROGRAM, author="test")
        library.release(session, "O01234.nc", 1, actor="test")
        auth.create_user(session, "op", Role.OPERATOR)
        key = auth.create_key(session, "op", Role.OPERATOR, label="test")[1]
        page_key = auth.create_key(
            session, "op", Role.OPERATOR, label=auth.SESSION_LABEL, action="login"
        )[1]
    with serving(server) as url, httpx.Client(base_url=url, timeout=30) as client:
        wait_for("the drop machine online", lambda: server.machines.machines["dropper"].online)
        reply = client.post(
            "/api/jobs", json={"program": "O01234.nc", "machines": ["dropper"]}, headers=bearer(key)
        )
        assert reply.status_code in (200, 201), reply.text
        ids = [job["id"] for job in reply.json()]
        (job,) = wait_jobs(client, key, ids)
        assert job["state"] == "done", job
        assert job["machine"] == "dropper"
        arrived = drop / "O01234.nc"
        assert hashlib.sha256(arrived.read_bytes()).digest() == hashlib.sha256(PROGRAM).digest()
        assert [p.name for p in drop.iterdir()] == ["O01234.nc"]  # no part file left behind
        # the page names the kind by its own label
        cookie = {
            "Cookie": f"{web_session.COOKIE}={page_key}",
            web_session.CSRF_HEADER: web_session.csrf_token(page_key),
        }
        page = client.get("/machines/dropper", headers=cookie)
        assert page.status_code == 200, page.text
        assert LABEL in page.text


def test_an_unregistered_kind_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="kind"):
        parse_config(_config(tmp_path, tmp_path), base=tmp_path)


# The names generic code must not use: the concrete kinds' classes and their packages.
CONCRETE = {
    "Lsv2Machine", "HaasNgcMachine", "HaasSerialMachine", "MtconnectMachine", "SerialMachine",
    "Lsv2Connector", "HaasNgcConnector", "HaasSerialConnector", "MtconnectConnector",
    "TapeConnector", "LSV2_SERIAL",
}  # fmt: skip


def _kind_packages() -> set[str]:
    return {p.name for p in (SERVER / "kinds").iterdir() if (p / "__init__.py").is_file()}


def _offences(path: Path, kinds: set[str]) -> list[str]:
    """Where ``path`` names a concrete kind: a class of one, or an import of its package."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Name) and node.id in CONCRETE:
            found.append(f"{node.lineno}: {node.id}")
        elif isinstance(node, ast.Attribute) and node.attr in CONCRETE:
            found.append(f"{node.lineno}: .{node.attr}")
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            names = {a.name for a in node.names}
            parts = module.split(".")
            if module.startswith("opendnc.server.kinds") and (
                (len(parts) > 3 and parts[3] in kinds)
                or (module == "opendnc.server.kinds" and names & kinds)
            ):
                found.append(f"{node.lineno}: from {module} import {', '.join(sorted(names))}")
            if names & CONCRETE:
                found.append(f"{node.lineno}: imports {', '.join(sorted(names & CONCRETE))}")
        elif isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[:3] == ["opendnc", "server", "kinds"] and parts[3:4] and parts[3] in kinds:
                    found.append(f"{node.lineno}: import {alias.name}")
    return found


def test_generic_server_code_names_no_concrete_kind() -> None:
    kinds = _kind_packages()
    assert {"lsv2", "haas_ngc", "haas_serial", "mtconnect", "serial"} <= kinds
    allowed = {SERVER / "kinds" / k for k in kinds}
    registry = SERVER / "kinds" / "registry.py"  # the one table: one line per kind
    offences = {}
    for path in sorted(SERVER.rglob("*.py")):
        if path == registry or any(folder in path.parents for folder in allowed):
            continue
        found = _offences(path, kinds)
        if found:
            offences[str(path.relative_to(SERVER))] = found
    assert offences == {}


def test_the_scan_sees_a_concrete_name(tmp_path: Path) -> None:
    """The scan itself finds each way of naming a kind (else the test above proves nothing)."""
    sample = tmp_path / "sample.py"
    sample.write_text(
        "from opendnc.server.kinds.lsv2 import SPEC\n"
        "from opendnc.server.kinds import haas_ngc\n"
        "import opendnc.server.kinds.serial.connector\n"
        "from opendnc.server.config.shop import MachineConfig\n"
        "def f(m: MachineConfig) -> bool:\n"
        "    return isinstance(m, HaasNgcMachine)\n"
    )
    found = _offences(sample, _kind_packages())
    assert [f.split(":")[0] for f in found] == ["1", "2", "3", "6"], found


def test_registering_a_taken_key_is_refused(drop_kind: KindSpec[DropMachine]) -> None:
    register(drop_kind)  # the same spec again: nothing changes
    other = KindSpec(
        kind="lsv2",
        label="not a TNC",
        schema=DropMachine,
        keys=frozenset(),
        parse=_parse,
        connector=_connector,
        capabilities=lambda config: Capabilities(),
    )
    with pytest.raises(InputError, match="lsv2"):
        register(other)
