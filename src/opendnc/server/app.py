"""Build the server: the database, its components and the API in one FastAPI app.

``build()`` only assembles: it registers every part of the server as a component of one
:class:`~opendnc.server.core.components.Core` (docs/server.md#shape-components-and-kinds); the app's
one lifespan starts them in dependency order and stops them in reverse within a deadline, so a
test can build the whole server around virtual controls and run it under uvicorn or an
in-process client alike.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import replace
from functools import partial

from fastapi import FastAPI
from sqlalchemy import Engine
from sqlalchemy.orm import Session, sessionmaker

from opendnc import __version__
from opendnc.server import actions, web
from opendnc.server.access.key_use import KeyUse
from opendnc.server.access.refusals import Refusals
from opendnc.server.access.throttle import Throttle
from opendnc.server.alerts.component import Alerts
from opendnc.server.cluster.cluster import Cluster
from opendnc.server.cluster.single_server import DatabaseInUse, ServerLock, refuse_beside_a_cluster
from opendnc.server.config.shop import ConfigError, MachineConfig, ShopConfig
from opendnc.server.core.components import STOP_DEADLINE, Core, Duty, DutyFlag, core_of
from opendnc.server.core.events import EventBus, ProgramChanged
from opendnc.server.core.loopwatch import LoopWatch
from opendnc.server.fleet.remote_request import RemoteRequests
from opendnc.server.fleet.shared_status import SharedStatus
from opendnc.server.fleet.tasks import ConnectorFactory, Fleet
from opendnc.server.http import alerts as alerts_api
from opendnc.server.http import api, edge
from opendnc.server.http import dprnt as dprnt_api
from opendnc.server.http import utilization as utilization_routes
from opendnc.server.http.clients import Clients, SendTimeout
from opendnc.server.http.deps import Database
from opendnc.server.http.limits import LimitsMiddleware
from opendnc.server.jobs.executors import default_executors
from opendnc.server.jobs.runner import JobRunner
from opendnc.server.kinds.connector import Connector
from opendnc.server.kinds.registry import connector_for, shares_of
from opendnc.server.library.watcher import LibraryWatcher
from opendnc.server.machines.autoreceive import AutoReceive
from opendnc.server.machines.dprnt_capture import DprntCapture
from opendnc.server.machines.leases import LIBRARY, Leases, held_elsewhere
from opendnc.server.machines.state import Machines
from opendnc.server.machines.timeline import Timeline
from opendnc.server.netshare.ftpserver import FtpServer, accounts_for
from opendnc.server.netshare.share import NetShare, local_now
from opendnc.server.outputs.mqtt import MqttPublisher
from opendnc.server.outputs.parts import Outputs, TimelineRecorder
from opendnc.server.outputs.shdr import MtconnectOutput
from opendnc.server.outputs.sparkplug import SparkplugNode
from opendnc.server.outputs.sparkplug_store import next_bd_seq
from opendnc.server.reports import routes as shift_routes
from opendnc.server.reports.mail import ShiftMailer
from opendnc.server.store.db import DatabaseUnreachable, make_engine, make_sessions, migrate
from opendnc.server.store.secrets import DEVICE_COOKIE_KEY, shared_secret
from opendnc.server.utilization import component as utilization_component

__all__ = ["ConnectorFactory", "Server", "build"]


class Server:
    """One built server: its app, and typed ways into the app's one registry (the core).

    It keeps no part of its own: each property asks the core (``server.runner`` is
    ``server.core.get(JobRunner)``), so there is one list of the server's parts.
    """

    def __init__(self, app: FastAPI) -> None:
        self.app = app

    @property
    def core(self) -> Core:
        """Every component of the server."""
        return core_of(self.app)

    @property
    def machines(self) -> Machines:
        """The machines' live state (and the event bus, the configuration)."""
        return self.core.get(Machines)

    @property
    def config(self) -> ShopConfig:
        """The shop's configuration the server was built from."""
        return self.machines.config

    @property
    def bus(self) -> EventBus:
        """The event bus."""
        return self.machines.bus

    @property
    def engine(self) -> Engine:
        """The database engine (disposed by whoever built the server)."""
        return self.core.get(Database).engine

    @property
    def sessions(self) -> sessionmaker[Session]:
        """Sessions of the database."""
        return self.core.get(Database).sessions

    @property
    def runner(self) -> JobRunner:
        """The job runner."""
        return self.core.get(JobRunner)

    @property
    def fleet(self) -> Fleet:
        """The machines' tasks."""
        return self.core.get(Fleet)

    @property
    def outputs(self) -> Outputs:
        """The open outputs (MQTT, MTConnect, Sparkplug; None where not configured)."""
        return self.core.get(Outputs)

    @property
    def cluster(self) -> Cluster | None:
        """The cluster component; None for a server alone."""
        return self.core.find(Cluster)


def build(
    config: ShopConfig,
    *,
    database: str | None = None,
    connector_factory: ConnectorFactory | None = None,
    sweep_interval: float = 5.0,
    retry_backoff: float = 2.0,
    stop_deadline: float = STOP_DEADLINE,
) -> Server:
    """Migrate the database and assemble the app (nothing runs until its lifespan starts).

    ``connector_factory`` replaces the kinds' own connectors (tests with a fake control).
    On PostgreSQL the server joins the database's cluster (docs/server.md#several-servers):
    it serves the machines whose lease it holds, and the library watcher and the net share
    only while it holds the shop-wide duties' lease.
    """
    url = database or config.server.database
    engine = make_engine(url)
    # PostgreSQL is shared with other servers unless this one is configured as the only one
    clustered = engine.dialect.name == "postgresql" and config.server.cluster
    migrate(engine)
    sessions = make_sessions(engine)
    server_lock = _server_lock(config, url, engine, sessions, clustered)
    bus = EventBus()
    for folder in (config.library.path, config.library.inbox, config.library.archive):
        folder.mkdir(parents=True, exist_ok=True)

    core = Core()
    # every user of the database stops before the lock that keeps a lone server apart goes
    lock_needs = (server_lock.name,) if server_lock is not None else ()
    database_part = core.add(Database(engine, sessions, needs=lock_needs))
    if server_lock is not None:
        core.add(server_lock)
    machines = core.add(Machines(config, bus))
    # every command of the API and the pages goes through the actions (docs/server.md)
    # device cookies are signed with the database's key: good on every server and after a restart
    guard = Throttle(secret=shared_secret(sessions, DEVICE_COOKIE_KEY))
    services = core.add(actions.Services(sessions, database_part.reads, machines, guard=guard))
    core.add(KeyUse(sessions))  # the keys' last use, written once a minute
    core.add(Refusals(sessions))  # refused logins and keys, one audit row a minute per source
    clients = core.add(Clients(config.clients))  # send timeout, event stream slots
    capture = core.add(DprntCapture(machines, sessions))
    runner = _runner(core, config, sessions, machines, sweep_interval, retry_backoff)
    requests = core.add(RemoteRequests(machines, services, config.requests, config.library.inbox))
    autoreceive = core.add(AutoReceive(machines, sessions))
    listeners = _outputs(core, config, sessions, bus)
    _timeline(core, config, sessions, bus, clustered)

    def connectors(machine: MachineConfig) -> Connector:
        # a serial Haas's printed lines go to the capture's sink for it
        hooks = capture.hooks_for(machine)
        # a control that reports nothing tells through the connector what the server does
        hooks = replace(hooks, on_status=partial(machines.note_status, machine.name))
        return connector_for(machine, hooks)

    factory = connector_factory or connectors
    fleet = core.add(
        Fleet(
            machines,
            runner,
            requests,
            autoreceive,
            factory,
            serve_all=not clustered,
            listeners=listeners,
        )
    )
    core.add(LoopWatch())
    # the shop-wide duties: components of the core, working while this server holds the
    # duty (alone: always; in a cluster: while the cluster holds the duties' lease)
    duty = DutyFlag(held=not clustered)
    core.add(Duty(_watcher(config, sessions, bus), duty))
    netshare = _netshare(config, services, sessions, bus)
    if netshare is not None:
        core.add(Duty(netshare, duty))
    # the boards that are FTP clients: this server's own ones only (docs/files.md)
    accounts = accounts_for(config.machines, config.server.name, clustered)
    if config.ftp_server is not None and accounts:
        core.add(FtpServer(config.ftp_server, accounts))
    if clustered:
        _cluster(core, config, url, sessions, machines, runner, fleet, duty)
    return Server(_web_app(core, clients, stop_deadline))


def _runner(
    core: Core,
    config: ShopConfig,
    sessions: sessionmaker[Session],
    machines: Machines,
    sweep_interval: float,
    retry_backoff: float,
) -> JobRunner:
    """The job runner and its executors."""
    backups = config.library.backups or config.library.archive / "backups"
    executors = [core.add(e) for e in default_executors(sessions, config.library.inbox, backups)]
    return core.add(
        JobRunner(
            machines,
            sessions,
            executors,
            worker=config.server.name,
            sweep_interval=sweep_interval,
            retry_backoff=retry_backoff,
            resume_wait=config.server.resume_wait,
        )
    )


def _outputs(
    core: Core, config: ShopConfig, sessions: sessionmaker[Session], bus: EventBus
) -> tuple[str, ...]:
    """The open outputs (MQTT, MTConnect, Sparkplug), and the alerts where configured; the
    names of the optional ones the machines' first statuses must find listening."""
    core.add(
        Outputs(_mqtt(config, bus), _mtconnect(config, bus), _sparkplug(config, bus, sessions))
    )
    if config.alerts is None:
        return ()
    # e-mail and webhooks (docs/server.md#alerts)
    alerts = core.add(Alerts(config.alerts, bus, sessions, config.calendar, config.server.name))
    return (alerts.name,)


def _watcher(config: ShopConfig, sessions: sessionmaker[Session], bus: EventBus) -> LibraryWatcher:
    """The library folder's watcher (run as a duty: alone, or by the cluster's holder)."""
    return LibraryWatcher(
        config.library.path,
        sessions,
        poll=config.library.poll,
        on_version=lambda name, number: bus.publish(ProgramChanged(name, number, "watcher")),
    )


def _server_lock(
    config: ShopConfig,
    url: str,
    engine: Engine,
    sessions: sessionmaker[Session],
    clustered: bool,
) -> ServerLock | None:
    """On PostgreSQL, the lock that keeps a lone server and a cluster apart, taken."""
    if engine.dialect.name != "postgresql":
        return None
    # a lone server holds the lock exclusively, a cluster's shared: each refuses beside
    # the other (a lone server writes no rows a cluster server could see)
    server_lock = ServerLock(url, alone=not clustered)
    try:
        server_lock.acquire()
        if not clustered:
            refuse_beside_a_cluster(sessions, config.server.name)
    except (DatabaseInUse, DatabaseUnreachable):
        server_lock.release()
        engine.dispose()
        raise
    return server_lock


def _timeline(
    core: Core, config: ShopConfig, sessions: sessionmaker[Session], bus: EventBus, clustered: bool
) -> Timeline:
    """The status timeline and its recorder, and utilization summing its finished hours."""
    timeline = Timeline(sessions, retention_days=config.server.timeline_days)
    names = [m.name for m in config.machines]
    core.add(
        TimelineRecorder(
            timeline,
            bus,
            server=config.server.name,
            machines=names,
            held_elsewhere=(lambda: held_elsewhere(sessions, config.server.name))
            if clustered
            else None,
        )
    )
    core.add(utilization_component.HourSummer(sessions, names, config.calendar))
    alerts = config.alerts
    if alerts is not None and alerts.email is not None and config.calendar.shifts:
        # the shift report at each shift's end (docs/dashboard.md#shift-report)
        core.add(ShiftMailer(sessions, config, alerts.email, alerts.public_url))
    return timeline


def _netshare(
    config: ShopConfig, services: actions.Services, sessions: sessionmaker[Session], bus: EventBus
) -> NetShare | None:
    """The net share, where one is configured."""
    if config.netshare is None:
        return None
    shares = shares_of(config.machines)
    # what reaches a share is decided as a send is (actions.policy.authorize)
    gate = actions.policy.share_gate(services)
    zone = config.calendar.zone  # archive_at is on the shop's clock, not this computer's
    return NetShare(
        config.netshare,
        shares,
        config.library.inbox,
        sessions,
        bus,
        gate=gate,
        clock=lambda: local_now(zone),
    )


def _cluster(
    core: Core,
    config: ShopConfig,
    url: str,
    sessions: sessionmaker[Session],
    machines: Machines,
    runner: JobRunner,
    fleet: Fleet,
    duty: DutyFlag,
) -> Cluster:
    """The leases and the cluster component, which holds the shop-wide duty while it holds
    its lease."""
    pins = {m.name: frozenset(m.servers) for m in config.machines}
    pins[LIBRARY] = frozenset()
    leases = Leases(sessions, config.server.name, pins, ttl=config.server.lease_seconds)
    shared = core.add(SharedStatus(machines, sessions, config.server.name))
    return core.add(
        Cluster(
            leases,
            machines,
            runner,
            fleet,
            database_url=url,
            duty=duty,
            on_status=shared.wake,
        )
    )


def _web_app(core: Core, clients: Clients, stop_deadline: float) -> FastAPI:
    """The web app: the core started and stopped by its lifespan, the API and the pages."""

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        await core.start()
        try:
            yield
        finally:
            await core.stop(stop_deadline)

    app = FastAPI(title="opendnc", version=__version__, lifespan=lifespan)
    edge.install(app)  # bad input 422 with a printable echo, the unexpected 500 in one line
    app.add_middleware(LimitsMiddleware)  # request bodies: size and deadline while they stream
    # responses: a client that stops reading is cut (outermost: it finds the connection)
    app.add_middleware(SendTimeout, limits=lambda: clients.limits)
    app.state.core = core  # the one thing on app.state: routes get parts via server/http/deps.py
    api.install(app)
    app.include_router(dprnt_api.router)
    app.include_router(alerts_api.router)
    utilization_routes.install(app)
    web.install(app)
    app.include_router(shift_routes.router)  # a page built on the pages' templates
    return app


def _mqtt(config: ShopConfig, bus: EventBus) -> MqttPublisher | None:
    if config.mqtt is None:
        return None
    try:
        import aiomqtt  # noqa: F401  (a configured output that cannot run fails at start)
    except ImportError:
        raise ConfigError(
            "mqtt", "needs aiomqtt, part of the 'server' extra: pip install 'opendnc[server]'"
        ) from None
    return MqttPublisher(config.mqtt, config.server.name, [m.name for m in config.machines], bus)


def _sparkplug(
    config: ShopConfig, bus: EventBus, sessions: sessionmaker[Session]
) -> SparkplugNode | None:
    if config.sparkplug is None:
        return None
    # Left out, the node is the server's name: `serve --name` sets it after the file is read.
    spb = replace(config.sparkplug, node=config.sparkplug.node or config.server.name)
    for module in ("aiomqtt", "pysparkplug"):
        try:
            __import__(module)  # a configured output that cannot run fails at start
        except ImportError:
            raise ConfigError(
                "sparkplug",
                f"needs {module}, part of the 'server' extra: pip install 'opendnc[server]'",
            ) from None
    return SparkplugNode(
        spb,
        [m.name for m in config.machines],
        bus,
        lambda: next_bd_seq(sessions, spb.group, spb.node),
    )


def _mtconnect(config: ShopConfig, bus: EventBus) -> MtconnectOutput | None:
    if config.mtconnect is None:
        return None
    return MtconnectOutput(config.mtconnect, [m.name for m in config.machines], bus)
