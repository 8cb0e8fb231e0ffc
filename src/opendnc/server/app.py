"""Build the server: database, supervisor and API in one FastAPI app.

``build()`` only assembles; the app's lifespan starts the machine tasks and stops them, so a
test can build the whole server around virtual controls and run it under uvicorn or an
in-process client alike.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass

from fastapi import FastAPI
from sqlalchemy import Engine
from sqlalchemy.orm import Session, sessionmaker

from opendnc import __version__
from opendnc.server import api, dprnt_api, edge, web
from opendnc.server.config import ConfigError, MachineConfig, ShopConfig
from opendnc.server.dprnt_capture import DprntCapture
from opendnc.server.events import EventBus
from opendnc.server.limits import LimitsMiddleware
from opendnc.server.loopwatch import LoopWatch
from opendnc.server.machines import Connector, connector_for
from opendnc.server.mqtt import MqttPublisher
from opendnc.server.netshare import NetShare
from opendnc.server.shdr import MtconnectOutput
from opendnc.server.store.db import make_engine, make_sessions, migrate
from opendnc.server.supervisor import ConnectorFactory, Supervisor
from opendnc.server.watcher import LibraryWatcher

__all__ = ["Server", "build"]


@dataclass
class Server:
    """The parts of one running server."""

    config: ShopConfig
    engine: Engine
    sessions: sessionmaker[Session]
    bus: EventBus
    supervisor: Supervisor
    watcher: LibraryWatcher
    app: FastAPI
    netshare: NetShare | None = None
    dprnt: DprntCapture | None = None
    mqtt: MqttPublisher | None = None
    mtconnect: MtconnectOutput | None = None


def build(
    config: ShopConfig,
    *,
    database: str | None = None,
    connector_factory: ConnectorFactory = connector_for,
    sweep_interval: float = 5.0,
    retry_backoff: float = 2.0,
) -> Server:
    """Migrate the database and assemble the app (nothing runs until its lifespan starts)."""
    engine = make_engine(database or config.server.database)
    migrate(engine)
    sessions = make_sessions(engine)
    bus = EventBus()
    capture = DprntCapture(config.machines, sessions, bus)

    def connectors(machine: MachineConfig) -> Connector:
        connector = connector_factory(machine)
        capture.attach(machine, connector)  # a serial Haas's printed lines
        return connector

    supervisor = Supervisor(
        config,
        sessions,
        bus,
        connector_factory=connectors,
        sweep_interval=sweep_interval,
        retry_backoff=retry_backoff,
    )
    capture.on_line = supervisor.note_dprnt  # the newest line shows in the machine's status
    for folder in (config.library.path, config.library.inbox, config.library.archive):
        folder.mkdir(parents=True, exist_ok=True)

    watcher = LibraryWatcher(
        config.library.path,
        sessions,
        poll=config.library.poll,
        on_version=lambda name, number: bus.publish(
            "program", name, {"name": name, "version": number, "source": "watcher"}
        ),
    )

    netshare = None
    if config.netshare is not None:
        machines = {m.name: m for m in config.machines}
        netshare = NetShare(config.netshare, machines, config.library.inbox, sessions, bus)
    names = [m.name for m in config.machines]
    publisher = None
    if config.mqtt is not None:
        try:
            import aiomqtt  # noqa: F401  (a configured output that cannot run fails at start)
        except ImportError:
            raise ConfigError(
                "mqtt", "needs aiomqtt, part of the 'server' extra: pip install 'opendnc[server]'"
            ) from None
        publisher = MqttPublisher(config.mqtt, config.server.name, names, bus)
    mtconnect = None
    if config.mtconnect is not None:
        mtconnect = MtconnectOutput(config.mtconnect, names, bus)
    background: list[asyncio.Task[None]] = []
    loopwatch = LoopWatch()

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        background.append(asyncio.create_task(loopwatch.run(), name="loop-watch"))
        # The outputs subscribe before the machines' first status, so they miss nothing.
        if publisher is not None:
            background.append(asyncio.create_task(publisher.run(), name="mqtt"))
        if mtconnect is not None:
            await mtconnect.start()
            background.append(asyncio.create_task(mtconnect.run(), name="mtconnect"))
        await supervisor.start()
        watching = asyncio.create_task(watcher.run(), name="library-watcher")
        if netshare is not None:
            background.append(asyncio.create_task(netshare.run(), name="netshare"))
        capture.start()
        try:
            yield
        finally:
            for task in (watching, *background):
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
            background.clear()
            await capture.stop()
            await supervisor.stop()
            if mtconnect is not None:
                await mtconnect.close()

    app = FastAPI(title="opendnc", version=__version__, lifespan=lifespan)
    edge.install(app)  # bad input 422 with a printable echo, the unexpected 500 in one line
    app.add_middleware(LimitsMiddleware)  # request bodies: size and deadline while they stream
    api.install(app, sessions, supervisor)
    app.state.outputs = {"mqtt": publisher, "mtconnect": mtconnect}
    app.state.loopwatch = loopwatch
    app.include_router(dprnt_api.router)
    app.state.dprnt = capture  # the machine page shows each listener's last word
    web.install(app)
    return Server(
        config,
        engine,
        sessions,
        bus,
        supervisor,
        watcher,
        app,
        netshare,
        capture,
        publisher,
        mtconnect,
    )
