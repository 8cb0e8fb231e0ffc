"""One asyncua session per OPC UA server, shared by every machine read through it.

A control's own OPC UA server carries one machine; an aggregating gateway carries many. Every
``opcua`` machine with the same endpoint, security and user joins the one session open to that
server (counted: the last to leave closes it), the one subscription on it (a monitored item
per value of every machine, routed back by the server's handle), and the one browse of its
machines folder (each machine object found by its browse name once per session). A lost
session is lost for every machine on it: each of their supervisors reconnects once, the first
opens the new session and the others join it; an open that fails is reported to every machine
that waited for it, so a server that does not answer costs one timeout per wave, not one per
machine (docs/opcua-input.md#one-session-per-server).

Nodes are found by browsing level by level: every node of one depth of the paths read goes in
one Browse request, so a machine costs a handful of requests, whatever its depth.
"""

from __future__ import annotations

import asyncio
import logging
import time
import weakref
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.client.client import Client
from asyncua.common.subscription import Subscription
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from asyncua.ua.object_ids import ObjectIds
from asyncua.ua.uaerrors import UaError

from opendnc.errors import InputError, TransportError
from opendnc.server.kinds.opcua.schema import OpcuaMachine

__all__ = ["Session", "acquire", "release"]

log = logging.getLogger(__name__)

# Nodes per Browse request: servers limit it (MaxNodesPerBrowse); a modest batch stays under
# any limit we know of and still makes a machine's level one request.
BROWSE_BATCH = 100
# Machines that browse and subscribe on one session at once: hundreds at once would queue
# behind each other at the server past their timeout, fail and retry in a storm; a few at a
# time each finish well within it, and the rest wait without a timeout running.
SETUP_AT_ONCE = 8
ROOT = ua.NodeId(ua.Int32(ObjectIds.RootFolder))


@dataclass(frozen=True)
class SessionKey:
    """What makes two machines' sessions the same session."""

    endpoint: str
    security_policy: str
    security_mode: str
    certificate: str
    private_key: str
    server_certificate: str
    application_uri: str
    user: str
    password: str
    publishing_interval: float
    request_timeout: float
    watchdog: float

    @classmethod
    def of(cls, config: OpcuaMachine) -> SessionKey:
        """The key of ``config``'s session."""
        return cls(
            config.endpoint, config.security_policy, config.security_mode, config.certificate,
            config.private_key, config.server_certificate, config.application_uri, config.user,
            config.password, config.publishing_interval, config.request_timeout, config.watchdog,
        )  # fmt: skip


Setter = Callable[[Any], None]
EventSink = Callable[[Any], None]


class _Router:
    """The subscription's handler: each notification to the machine whose item it is."""

    def __init__(self) -> None:
        self.values: dict[int, Setter] = {}  # server handle -> setter
        self.events: dict[int, EventSink] = {}  # server handle -> the machine's sink

    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        setter = self.values.get(data.subscription_data.server_handle)
        if setter is not None:
            setter(val)

    def event_notification(self, event: Any) -> None:
        sink = self.events.get(getattr(event, "server_handle", -1))
        if sink is not None:
            sink(event)

    def status_change_notification(self, status: Any) -> None:
        log.info("subscription status: %s", status)


class Session:
    """One open session to one server, and what was learned on it."""

    def __init__(self, key: SessionKey, client: Client) -> None:
        self.key = key
        self.client = client
        self.users = 0
        self.lost: Exception | None = None
        self.closed = False
        self.router = _Router()
        self.subscription: Subscription | None = None
        self._subscribing = asyncio.Lock()
        self.setting_up = asyncio.Semaphore(SETUP_AT_ONCE)
        self._children: dict[ua.NodeId, list[ua.ReferenceDescription]] = {}
        self._folders: dict[str, asyncio.Task[ua.NodeId | None]] = {}
        self.namespaces: dict[str, int] = {}

    @property
    def security_policy_uri(self) -> str:
        """The URI of the session's security policy."""
        return str(self.client.security_policy.URI)

    async def on_lost(self, exc: Exception) -> None:
        log.info("%s: session lost: %r", self.key.endpoint, exc)
        self.lost = exc

    # -- browsing ---------------------------------------------------------------------------

    async def children(
        self, nodes: Iterable[ua.NodeId]
    ) -> dict[ua.NodeId, list[ua.ReferenceDescription]]:
        """The hierarchical children of every node, browsed in as few requests as will do
        (each node once per session)."""
        wanted = list(dict.fromkeys(nodes))
        missing = [n for n in wanted if n not in self._children]
        for start in range(0, len(missing), BROWSE_BATCH):
            batch = missing[start : start + BROWSE_BATCH]
            params = ua.BrowseParameters()
            params.View.Timestamp = ua.get_win_epoch()
            params.RequestedMaxReferencesPerNode = 0
            for node in batch:
                desc = ua.BrowseDescription()
                desc.NodeId = node
                desc.BrowseDirection = ua.BrowseDirection.Forward
                desc.ReferenceTypeId = ua.NodeId(ua.Int32(ObjectIds.HierarchicalReferences))
                desc.IncludeSubtypes = True
                desc.NodeClassMask = ua.NodeClass.Unspecified
                desc.ResultMask = ua.BrowseResultMask.All
                params.NodesToBrowse.append(desc)
            results = await self.client.uaclient.browse(params)
            for node, result in zip(batch, results, strict=False):
                references = list(result.References or [])
                point = result.ContinuationPoint
                while point:
                    more = ua.BrowseNextParameters()
                    more.ContinuationPoints = [point]
                    more.ReleaseContinuationPoints = False
                    following = await self.client.uaclient.browse_next(more)
                    if not following:
                        break
                    references.extend(following[0].References or [])
                    point = following[0].ContinuationPoint
                self._children[node] = references
        return {n: self._children[n] for n in wanted}

    async def resolve(
        self, base: ua.NodeId, paths: Iterable[tuple[str, ...]]
    ) -> dict[tuple[str, ...], ua.NodeId | None]:
        """The node at each path of browse names (the ``Name`` part, any namespace) below
        ``base``; None where a part is missing. One Browse request per depth."""
        paths = list(paths)
        found: dict[tuple[str, ...], ua.NodeId | None] = {(): base}
        depth = max((len(p) for p in paths), default=0)
        for level in range(1, depth + 1):
            prefixes = {p[:level] for p in paths if len(p) >= level}
            parents = {found[p[:-1]] for p in prefixes if found.get(p[:-1]) is not None}
            children = await self.children(n for n in parents if n is not None)
            for prefix in prefixes:
                parent = found.get(prefix[:-1])
                found[prefix] = None if parent is None else _named(children[parent], prefix[-1])
        return {p: found.get(p) for p in paths}

    async def folder_child(self, root: str, name: str) -> ua.NodeId | None:
        """The child ``name`` of the folder at browse path ``root`` from the Root folder (the
        folder browsed once per session for all its machines)."""
        task = self._folders.get(root)
        if task is None or (task.done() and (task.cancelled() or task.exception())):
            # (a browse that failed is tried again by the next machine, not kept as the answer)
            parts = tuple(part for part in root.split("/") if part)
            root_id = ROOT
            task = asyncio.ensure_future(self._folder(root_id, parts))
            self._folders[root] = task
        folder = await asyncio.shield(task)
        if folder is None:
            return None
        return _named((await self.children([folder]))[folder], name)

    async def _folder(self, root: ua.NodeId, parts: tuple[str, ...]) -> ua.NodeId | None:
        folder = (await self.resolve(root, [parts]))[parts]
        if folder is not None:
            await self.children([folder])
        return folder

    async def namespace(self, uri: str) -> int:
        """The index of namespace ``uri`` on this server (0 where it has none)."""
        if uri not in self.namespaces:
            try:
                self.namespaces[uri] = int(await self.client.get_namespace_index(uri))
            except ValueError:
                self.namespaces[uri] = 0
        return self.namespaces[uri]

    async def ensure_subscription(self) -> Subscription:
        """The session's one subscription (made by the first machine that needs it)."""
        async with self._subscribing:
            if self.subscription is None:
                seconds = self.key.publishing_interval
                self.subscription = await self.client.create_subscription(
                    seconds * 1000, self.router
                )
            return self.subscription


def _named(references: list[ua.ReferenceDescription], name: str) -> ua.NodeId | None:
    for reference in references:
        if reference.BrowseName.Name == name:
            node: ua.NodeId = reference.NodeId
            return node
    return None


class _Pool:
    """The sessions of one event loop, by key."""

    def __init__(self) -> None:
        self.sessions: dict[SessionKey, Session] = {}
        self.locks: dict[SessionKey, asyncio.Lock] = {}
        self.failures: dict[SessionKey, tuple[float, Exception]] = {}
        self.opened = 0  # sessions opened (tests, benchmarks)


_POOLS: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, _Pool] = weakref.WeakKeyDictionary()


def pool() -> _Pool:
    """The pool of the running loop (a test's servers each run a loop of their own)."""
    loop = asyncio.get_running_loop()
    found = _POOLS.get(loop)
    if found is None:
        found = _POOLS[loop] = _Pool()
    return found


async def acquire(config: OpcuaMachine) -> Session:
    """Join the live session for ``config``'s server, opening it if there is none."""
    key = SessionKey.of(config)
    sessions = pool()
    asked = time.monotonic()
    lock = sessions.locks.setdefault(key, asyncio.Lock())
    async with lock:
        session = sessions.sessions.get(key)
        if session is None or session.lost is not None or session.closed:
            failure = sessions.failures.get(key)
            if failure is not None and failure[0] >= asked:
                # the open this machine waited for failed: the same answer, not another wait
                raise TransportError(f"{config.name}: {failure[1]}")
            try:
                session = await _open(key, config)
            except TransportError as exc:
                sessions.failures[key] = (time.monotonic(), exc)
                raise TransportError(f"{config.name}: {exc}") from None
            sessions.sessions[key] = session
            sessions.opened += 1
        session.users += 1
        return session


async def release(session: Session) -> None:
    """Leave ``session``; the last machine to leave closes it."""
    session.users -= 1
    if session.users > 0:
        return
    sessions = pool()
    if sessions.sessions.get(session.key) is session:
        del sessions.sessions[session.key]
    session.closed = True
    client = session.client
    if session.lost is not None:
        client.disconnect_socket()
        return
    try:
        async with asyncio.timeout(session.key.request_timeout):
            await client.disconnect()
    except (TimeoutError, OSError, UaError, ConnectionError):
        client.disconnect_socket()


async def _open(key: SessionKey, config: OpcuaMachine) -> Session:
    client = Client(key.endpoint, timeout=key.request_timeout, watchdog_intervall=key.watchdog)
    client.application_uri = key.application_uri
    if key.user:
        client.set_user(key.user)
        client.set_password(key.password)
    session = Session(key, client)
    client.connection_lost_callback = session.on_lost
    try:
        async with asyncio.timeout(key.request_timeout * 3):
            if key.security_policy == "Basic256Sha256":
                await _secure(client, config)
            await client.connect()
    except TimeoutError:
        client.disconnect_socket()
        raise TransportError(f"{key.endpoint} did not answer") from None
    except (OSError, UaError, ConnectionError) as exc:
        client.disconnect_socket()
        raise TransportError(f"{key.endpoint}: {exc}") from None
    return session


async def _secure(client: Client, config: OpcuaMachine) -> None:
    for key in ("certificate", "private_key"):
        if not Path(getattr(config, key)).is_file():
            raise InputError(f"{config.name}: {key} {getattr(config, key)!r} is not a file")
    mode = getattr(ua.MessageSecurityMode, config.security_mode)
    await client.set_security(
        SecurityPolicyBasic256Sha256,
        certificate=config.certificate,
        private_key=config.private_key,
        server_certificate=config.server_certificate or None,
        mode=mode,
    )
