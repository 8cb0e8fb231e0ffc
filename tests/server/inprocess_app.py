"""The whole server in this process, around controls that live in memory.

``build(connector_factory=...)`` puts a :class:`MemoryControl` behind every machine: a
connector that keeps its files in a dict and answers at once, so a test of the API and the
pages (roles, policies, the contract) runs in milliseconds per request, with the real
database, actions, routes, runner and event bus. The protocols themselves are tested
against the virtual controls elsewhere (tests/server/test_end_to_end.py and others).
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from tests.peers import require_module

httpx = require_module("httpx")
require_module("jinja2")
uvicorn = require_module("uvicorn")

from opendnc.errors import ControlRefused, InputError  # noqa: E402
from opendnc.server.access import auth  # noqa: E402
from opendnc.server.app import Server, build  # noqa: E402
from opendnc.server.config.shop import MachineConfig, parse_config  # noqa: E402
from opendnc.server.core.status import (  # noqa: E402
    DripProgress,
    MachineStatus,
    Progress,
)
from opendnc.server.kinds.connector import Reception  # noqa: E402
from opendnc.server.kinds.files import RemoteFile  # noqa: E402
from opendnc.server.store.models import Role  # noqa: E402
from opendnc.server.web import session as web_session  # noqa: E402
from tests.server.harness import wait_for  # noqa: E402
from tests.server.serving import serving  # noqa: E402

ROLES = [Role.VIEWER, Role.OPERATOR, Role.PROGRAMMER, Role.APPROVER, Role.ADMIN]


@dataclass
class MemoryControl:
    """A control whose files are a dict (``TNC:/nc_prog/X.H`` -> bytes)."""

    config: MachineConfig
    files: dict[str, bytes] = field(default_factory=dict)
    listens: bool = False
    online: bool = True  # False: connect() fails like an unreachable control
    line_time: float = 0.0  # seconds a drip-feed takes per line
    chunk_time: float = 0.0  # seconds a load takes per tenth of the program
    connects: int = 0  # how often a link was opened to this control

    async def connect(self) -> None:
        self.connects += 1
        if not self.online:
            raise ControlRefused(f"{self.config.name}: no answer")

    async def close(self) -> None:
        return None

    async def status(self) -> MachineStatus:
        return MachineStatus(at=datetime.now(UTC), available=True, execution="READY")

    def _folder(self) -> str:
        return (getattr(self.config, "folder", "") or "TNC:/nc_prog").rstrip("/")

    async def send(self, name: str, data: bytes, progress: Progress) -> None:
        if self.chunk_time:
            # in tenths, as a slow link reports; ``progress`` may raise to stop the load
            for tenth in range(1, 10):
                await asyncio.sleep(self.chunk_time)
                progress(len(data) * tenth // 10, len(data))
        self.files[f"{self._folder()}/{name}"] = data
        progress(len(data), len(data))

    async def verify(self, name: str, data: bytes) -> bool | None:
        return self.files.get(f"{self._folder()}/{name}") == data

    async def listen(self, seconds: float) -> Reception | None:
        return None

    async def fetch(self, path: str) -> bytes:
        if path not in self.files:
            raise ControlRefused(f"{path}: no such file")
        return self.files[path]

    async def delete(self, path: str) -> None:
        if self.files.pop(path, None) is None:
            raise ControlRefused(f"{path}: no such file")

    async def backup(self, path: str, target: Path) -> dict[str, int]:
        return {"copied": 0, "unchanged": 0, "failed": 0}

    async def dripfeed(
        self, name: str, data: bytes, from_line: int, progress: DripProgress
    ) -> dict[str, int]:
        # a line every line_time seconds; ``progress`` may raise to stop the feed
        lines = data.splitlines(keepends=True)
        fed = 0
        for n, line in enumerate(lines[from_line - 1 :], start=from_line):
            await asyncio.sleep(self.line_time)
            fed += len(line)
            progress(n + 1, len(lines), fed, len(data))
        return {"lines": len(lines)}

    async def list_files(self, folder: str) -> list[RemoteFile]:
        base = folder.rstrip("/")
        at = datetime(2026, 1, 1, tzinfo=UTC)
        names = {p[len(base) + 1 :] for p in self.files if p.startswith(base + "/")}
        entries = []
        for rest in sorted(names):
            if "/" in rest:
                entries.append(RemoteFile(rest.split("/")[0], f"{base}/{rest}", 0, at, True))
            else:
                size = len(self.files[f"{base}/{rest}"])
                entries.append(RemoteFile(rest, f"{base}/{rest}", size, at, False))
        return entries

    async def put_file(self, path: str, data: bytes, progress: Progress) -> None:
        if not path.upper().startswith("TNC:/"):
            raise InputError(f"{path}: not on the control")
        self.files[path] = data
        progress(len(data), len(data))


def config_text(tmp_path: Path, machines: list[dict[str, object]], check: str | None = None) -> str:
    """A configuration for ``machines`` (each a table of ``[[machines]]``); ``check`` is the
    library's ``block`` (the default) or ``warn`` for program check errors."""

    def value(v: object) -> str:
        if isinstance(v, dict):  # a TOML inline table (travel = { x = [-30.0, 0.0] })
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        return json.dumps(v) if not isinstance(v, bool) else str(v).lower()

    lines = [
        "[library]",
        f"path = {value(str(tmp_path / 'lib'))}",
        f"inbox = {value(str(tmp_path / 'inbox'))}",
        f"archive = {value(str(tmp_path / 'archive'))}",
        *([f"check = {value(check)}"] if check else []),
    ]
    for machine in machines:
        lines += ["", "[[machines]]", *(f"{k} = {value(v)}" for k, v in machine.items())]
    return "\n".join(lines) + "\n"


@dataclass
class App:
    """The server, its in-process client, and the memory controls by machine name."""

    server: Server
    client: Any  # an httpx.Client on the server's URL
    controls: dict[str, MemoryControl]
    api_keys: dict[Role, str]
    session_keys: dict[Role, str]

    def api(self, role: Role) -> dict[str, str]:
        """Headers of an API request as ``role``."""
        return {"Authorization": f"Bearer {self.api_keys[role]}"}

    def page(self, role: Role) -> dict[str, str]:
        """Headers of a page's write as ``role`` (its session cookie and CSRF token)."""
        key = self.session_keys[role]
        return {
            "Cookie": f"{web_session.COOKIE}={key}",
            web_session.CSRF_HEADER: web_session.csrf_token(key),
        }


@contextmanager
def running(
    tmp_path: Path,
    machines: list[dict[str, object]],
    offline: tuple[str, ...] = (),
    extra: str = "",
    check: str | None = None,
    database: str | None = None,
) -> Iterator[App]:
    """The server for ``machines`` on memory controls, started, with a key and a web
    session for a user of every role; the ``offline`` ones never answer. ``extra`` is TOML
    put before the machines (``[server]``, outputs); ``check`` as in :func:`config_text`;
    ``database`` a URL (a SQLite file in ``tmp_path`` if None)."""
    controls: dict[str, MemoryControl] = {}

    def connector(config: MachineConfig) -> MemoryControl:
        control = controls.setdefault(
            config.name, MemoryControl(config, online=config.name not in offline)
        )
        control.config = config
        return control

    config = parse_config(extra + "\n" + config_text(tmp_path, machines, check), base=tmp_path)
    server = build(
        config,
        database=database or f"sqlite:///{tmp_path / 'db.sqlite'}",
        connector_factory=connector,
    )
    api_keys: dict[Role, str] = {}
    session_keys: dict[Role, str] = {}
    with server.sessions.begin() as session:
        for role in ROLES:
            name = role.name.lower()
            auth.create_user(session, name, role)
            api_keys[role] = auth.create_key(session, name, role, label="test")[1]
            session_keys[role] = auth.create_key(
                session, name, role, label=auth.SESSION_LABEL, action="login"
            )[1]
    with serving(server) as url:
        wait_for(
            "the machines online",
            lambda: all(
                m.online for m in server.machines.machines.values() if m.config.name not in offline
            ),
            timeout=30,
        )
        with httpx.Client(base_url=url, timeout=30) as client:
            yield App(server, client, controls, api_keys, session_keys)
