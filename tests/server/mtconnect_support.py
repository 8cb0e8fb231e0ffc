"""A virtual MTConnect agent on an event loop of its own thread, and the server reading it:
the agent and the server talk HTTP over loopback sockets, as an agent and a DNC server do."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from tests.peers import require_module

httpx = require_module("httpx")
require_module("lxml")
uvicorn = require_module("uvicorn")

from opendnc.server.access import auth  # noqa: E402
from opendnc.server.app import Server, build  # noqa: E402
from opendnc.server.config.shop import MachineConfig, parse_config  # noqa: E402
from opendnc.server.kinds.connector import Connector  # noqa: E402
from opendnc.server.kinds.registry import connector_for  # noqa: E402
from opendnc.server.store.models import Role  # noqa: E402
from opendnc.server.web import session as web_session  # noqa: E402
from opendnc.sim.mtconnect.agent import VirtualAgent  # noqa: E402
from opendnc.sim.mtconnect.machine import ScriptedMachine  # noqa: E402
from tests.server.inprocess_app import config_text  # noqa: E402
from tests.server.serving import serving  # noqa: E402

T = TypeVar("T")


class AgentThread:
    """A :class:`VirtualAgent` for ``names`` served from a loop in a thread of its own."""

    def __init__(self, names: list[str], **options: Any) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.agent: VirtualAgent = self.call(lambda: VirtualAgent(names, **options))
        self.run(self.agent.start)
        self.machines = {name: ScriptedMachine(self.agent, name) for name in names}

    def run(self, make: Callable[[], Any]) -> Any:
        """Run a coroutine on the agent's loop and wait for it."""
        return asyncio.run_coroutine_threadsafe(make(), self.loop).result(30)

    def call(self, fn: Callable[[], T]) -> T:
        """Run ``fn`` on the agent's loop (its values change there) and wait for it."""
        future: Future[T] = Future()

        def go() -> None:
            try:
                future.set_result(fn())
            except BaseException as exc:
                future.set_exception(exc)

        self.loop.call_soon_threadsafe(go)
        return future.result(10)

    def step(self, name: str, action: Callable[[ScriptedMachine], object]) -> float:
        """Do one scripted step on machine ``name``; the monotonic time it was done."""
        machine = self.machines[name]
        self.call(lambda: action(machine))
        return time.monotonic()

    def stop(self) -> None:
        self.run(self.agent.close)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)
        self.loop.close()


@contextmanager
def agent_thread(names: list[str], **options: Any) -> Iterator[AgentThread]:
    agent = AgentThread(names, **options)
    try:
        yield agent
    finally:
        agent.stop()


@dataclass
class Floor:
    """The server reading the agent: its HTTP client, a viewer's key, the connectors made."""

    server: Server
    client: Any
    key: str
    session: str
    connectors: dict[str, list[Connector]]

    def machine(self, name: str) -> dict[str, Any]:
        """The machine as ``/api/machines`` lists it."""
        answer = self.client.get("/api/machines", headers={"Authorization": f"Bearer {self.key}"})
        answer.raise_for_status()
        return next(m for m in answer.json() if m["name"] == name)

    def api(self, path: str, **params: Any) -> Any:
        """An API answer's JSON as the viewer gets it."""
        headers = {"Authorization": f"Bearer {self.key}"}
        answer = self.client.get(path, params=params, headers=headers)
        answer.raise_for_status()
        return answer.json()

    def page(self, path: str) -> str:
        """A page's HTML as the viewer sees it."""
        answer = self.client.get(path, headers={"Cookie": f"{web_session.COOKIE}={self.session}"})
        answer.raise_for_status()
        return str(answer.text)

    def until_each(
        self,
        what: str,
        checks: dict[str, Callable[[dict[str, Any]], bool]],
        since: dict[str, float],
    ) -> dict[str, float]:
        """Poll the floor until each machine's check holds; seconds from its ``since``. One
        list read every 20 ms serves every machine, so their waits overlap."""
        end = time.monotonic() + 5
        lags: dict[str, float] = {}
        while True:
            answer = self.client.get(
                "/api/machines", headers={"Authorization": f"Bearer {self.key}"}
            )
            answer.raise_for_status()
            now = time.monotonic()
            seen = {m["name"]: m for m in answer.json()}
            for name, check in checks.items():
                if name not in lags and check(seen[name]):
                    lags[name] = now - since[name]
            if len(lags) == len(checks):
                return lags
            if now > end:
                late = {n: seen[n] for n in checks if n not in lags}
                raise AssertionError(f"timed out waiting for {what}: {late!r}")
            time.sleep(0.02)

    def until(
        self, name: str, what: str, check: Callable[[dict[str, Any]], bool], since: float
    ) -> float:
        """:meth:`until_each` for one machine. The polls are 20 ms apart, not growing as the
        harness's ``wait_for``'s: the time measured is the floor's lag."""
        return self.until_each(what, {name: check}, {name: since})[name]


@contextmanager
def floor(tmp_path: Path, machines: list[dict[str, object]]) -> Iterator[Floor]:
    """The whole server for ``machines`` (real connectors), served on loopback, on SQLite."""
    made: dict[str, list[Connector]] = {}

    def connector(config: MachineConfig) -> Connector:
        made.setdefault(config.name, []).append(connector_for(config))
        return made[config.name][-1]

    config = parse_config(config_text(tmp_path, machines), base=tmp_path)
    server = build(
        config, database=f"sqlite:///{tmp_path / 'db.sqlite'}", connector_factory=connector
    )
    with server.sessions.begin() as session:
        auth.create_user(session, "viewer", Role.VIEWER)
        key = auth.create_key(session, "viewer", Role.VIEWER, label="test")[1]
        cookie = auth.create_key(
            session, "viewer", Role.VIEWER, label=auth.SESSION_LABEL, action="login"
        )[1]
    with serving(server) as url, httpx.Client(base_url=url, timeout=30) as client:
        yield Floor(server, client, key, cookie, made)
