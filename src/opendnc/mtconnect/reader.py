"""Reading one device of an MTConnect agent over HTTP (httpx), asyncio.

The loop is the one the standard's clients use (docs/mtconnect-input.md#reading): ``probe``
once, ``current`` for every value as it is, then one long ``sample?from=&interval=``
stream, resumed from the next sequence when it breaks. A new ``instanceId`` (the agent
restarted) means probe and current again; a gap (``OUT_OF_RANGE``, or a document whose
buffer starts past what we took) means current again. An agent that does not stream
(``UNSUPPORTED``, or a plain document where a stream was asked for) is polled with
``current`` instead. What the documents say is parsed by :mod:`.documents` and kept by
:mod:`.device_state`; this module only moves bytes.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from dataclasses import dataclass

import httpx

from opendnc.errors import RemoteProtocolError, TransportError, TransportTimeout, os_reason
from opendnc.mtconnect.device_state import DeviceState, Snapshot
from opendnc.mtconnect.documents import (
    AgentRefused,
    Streams,
    parse_devices,
    parse_streams,
)
from opendnc.mtconnect.multipart import MultipartSplitter, boundary_of

__all__ = ["DOCUMENT_DEADLINE", "MAX_DOCUMENT", "AgentReader", "ReaderCounts"]

log = logging.getLogger(__name__)

# The largest document taken (a probe of a big machine is a few hundred kB): a wrong URL, or
# a peer that sends one body for ever, would otherwise be held in memory whole.
MAX_DOCUMENT = 16 * 1024 * 1024
# Seconds one document may take to arrive whole: httpx's read timeout is per read, so a
# peer trickling a byte at a time would never time out without it.
DOCUMENT_DEADLINE = 30.0

# errorCode words that mean "this agent will not stream": poll current instead
_NO_STREAMING = frozenset({"UNSUPPORTED", "INVALID_REQUEST", "INVALID_QUERY_PARAMETER"})


class _Restarted(Exception):
    """The agent's instanceId changed under a stream."""


class _Gap(Exception):
    """Observations we had not taken left the agent's buffer."""


@dataclass
class ReaderCounts:
    """What happened on the link since the reader opened (for logs, tests and benchmarks)."""

    probes: int = 0
    currents: int = 0
    streams: int = 0  # sample streams opened
    documents: int = 0  # streamed documents taken
    restarts: int = 0  # instanceId changes seen
    gaps: int = 0  # resynchronisations after lost observations


class AgentReader:
    """One device of an agent at ``url`` (``http://host:port``, maybe with a path prefix).

    :meth:`open` probes and reads current; :meth:`follow` then keeps :meth:`snapshot` up to
    date until the agent cannot be reached, which it raises as a
    :class:`~opendnc.errors.TransportError` (the caller reconnects with :meth:`open`).
    A document larger than ``max_document`` bytes is a
    :class:`~opendnc.errors.RemoteProtocolError`; one that does not arrive whole within
    ``deadline`` seconds (a peer trickling bytes) a :class:`~opendnc.errors.TransportTimeout`.
    """

    def __init__(
        self,
        url: str,
        device: str = "",
        *,
        interval: float = 0.1,
        heartbeat: float = 1.0,
        timeout: float = 3.0,
        poll: float = 1.0,
        streaming: bool = True,
        count: int = 1000,
        grace: float = 2.0,
        max_document: int = MAX_DOCUMENT,
        deadline: float = DOCUMENT_DEADLINE,
    ) -> None:
        self.url = url.rstrip("/")
        self.device = device
        self.interval = interval
        self.heartbeat = heartbeat
        self.timeout = timeout
        self.poll = poll  # seconds between current requests when the agent does not stream
        self.streaming = streaming
        self.count = count
        # seconds an agent that refuses or drops connections is asked again before the
        # reader gives up: an agent restarting is back within them, and the machine's state
        # (the last values, kept meanwhile) does not flicker to offline for it
        self.grace = grace
        self.max_document = max_document  # bytes of one document, plain or streamed
        self.deadline = deadline  # seconds for one document to arrive whole
        self.counts = ReaderCounts()
        self.state: DeviceState | None = None
        self.changed = asyncio.Event()  # set whenever a document changed the state
        self._client: httpx.AsyncClient | None = None

    def _path(self, request: str) -> str:
        return f"{self.url}/{self.device}/{request}" if self.device else f"{self.url}/{request}"

    def snapshot(self) -> Snapshot:
        """The device's latest values (empty before :meth:`open`)."""
        return self.state.snapshot() if self.state is not None else Snapshot()

    async def open(self) -> Snapshot:
        """Probe the agent and read every current value."""
        if self._client is None:
            # Streams send at least one document per heartbeat: three missed ones is a dead link.
            timeout = httpx.Timeout(self.timeout, read=max(self.timeout, 3 * self.heartbeat))
            self._client = httpx.AsyncClient(timeout=timeout, trust_env=False)
        for _ in range(3):
            devices = parse_devices(await self._get(self._path("probe")))
            self.counts.probes += 1
            self.state = DeviceState(devices, self.device)
            try:
                await self._current()
            except _Restarted:
                continue  # it restarted between the two requests: probe the new one
            return self.snapshot()
        raise RemoteProtocolError(f"{self.url}: the agent restarts again and again")

    async def close(self) -> None:
        """Close the HTTP client; safe to call at any time."""
        client, self._client = self._client, None
        if client is not None:
            with contextlib.suppress(httpx.HTTPError, RuntimeError):
                await client.aclose()

    async def follow(self) -> None:
        """Keep the state up to date; returns never, raises when the agent is gone."""
        pending = ""  # "probe" or "current": what the next turn reads first
        idle = 0  # turns in a row that brought no streamed document
        lost: float | None = None  # when the agent stopped taking connections
        loop = asyncio.get_running_loop()
        while True:
            if idle >= 3:
                # an agent that ends every stream at once, is out of range at once again, or
                # restarts at every answer would be asked again and again
                raise RemoteProtocolError(f"{self.url}: the agent's stream brings nothing")
            try:
                if pending == "probe":
                    pending = ""
                    await self.open()
                elif pending == "current":
                    pending = ""
                    await self._current()
                elif self.streaming:
                    idle = 0 if await self._stream() else idle + 1
                    if idle:
                        await asyncio.sleep(self.interval)  # not back to back on an empty end
                else:
                    idle = 0
                    await asyncio.sleep(self.poll)
                    await self._current()
                lost = None
            except TransportTimeout:
                raise  # a silent agent is not restarting: it hangs
            except TransportError:
                lost = loop.time() if lost is None else lost
                if loop.time() - lost >= self.grace or self._client is None:
                    raise  # gone for good, or closed under us: not opened again here
                pending = "probe"  # when it answers again, maybe as a new instance
                await asyncio.sleep(min(0.2, self.grace / 4))
            except _Restarted:
                self.counts.restarts += 1
                log.info("%s: the agent restarted; probing again", self.url)
                # counted as a turn without a document: two agents answering in turn (behind
                # a balancer) would otherwise be probed again and again
                pending, idle = "probe", idle + 1
            except _Gap:
                self.counts.gaps += 1
                log.info("%s: observations were lost; reading current", self.url)
                pending, idle = "current", idle + 1
            except AgentRefused as exc:
                if "OUT_OF_RANGE" in exc.codes:
                    self.counts.gaps += 1
                    log.info("%s: out of the agent's buffer; reading current", self.url)
                    pending, idle = "current", idle + 1
                elif self.streaming and _NO_STREAMING & set(exc.codes):
                    log.info("%s: no streaming (%s); polling current", self.url, exc)
                    self.streaming = False
                else:
                    raise

    async def _current(self) -> None:
        assert self.state is not None
        current = parse_streams(await self._get(self._path("current")))
        self.counts.currents += 1
        if current.header.instance_id != self.state.instance_id:
            raise _Restarted
        self.state.load(current)
        self.changed.set()

    def _take(self, sample: Streams) -> None:
        state = self.state
        assert state is not None
        if sample.header.instance_id != state.instance_id:
            raise _Restarted
        if sample.header.first_sequence > state.last_sequence + 1:
            raise _Gap
        if state.update(sample):
            self.changed.set()

    async def _stream(self) -> int:
        """One sample stream from the next sequence, until it ends; the documents it held."""
        assert self.state is not None
        if self._client is None:
            raise TransportError(f"{self.url}: not open")  # closed under a running follow()
        params = {
            "from": str(self.state.last_sequence + 1),
            "count": str(self.count),
            "interval": str(round(self.interval * 1000)),
            "heartbeat": str(round(self.heartbeat * 1000)),
        }
        taken = 0
        loop = asyncio.get_running_loop()
        try:
            async with self._client.stream("GET", self._path("sample"), params=params) as answer:
                boundary = boundary_of(answer.headers.get("content-type", ""))
                if boundary is None:
                    # a plain document (an error, or an agent that does not stream)
                    async with asyncio.timeout(self.deadline):
                        body = await self._body(answer)
                    self._take(parse_streams(body))
                    self.streaming = False
                    return 1
                self.counts.streams += 1
                splitter = MultipartSplitter(boundary, max_part=self.max_document)
                due = loop.time() + self.deadline  # for the next document
                async for chunk in answer.aiter_bytes():
                    for part in splitter.feed(chunk):
                        self.counts.documents += 1
                        taken += 1
                        self._take(parse_streams(part))
                        due = loop.time() + self.deadline
                    if splitter.closed:
                        break
                    if loop.time() > due:  # bytes keep coming, a whole document does not
                        raise TransportTimeout(self._late())
        except TimeoutError:  # the plain document's deadline (asyncio's, not httpx's)
            raise TransportTimeout(self._late()) from None
        except httpx.TimeoutException:
            raise TransportTimeout(f"{self.url}: the agent's stream went silent") from None
        except (httpx.RemoteProtocolError, httpx.ReadError) as exc:
            if not taken:  # dropped before a document: the agent is going away
                raise TransportError(f"{self.url}: {_reason(exc)}") from None
            # the agent closed a stream that worked: resume it (a restart shows then)
        except httpx.HTTPError as exc:
            raise TransportError(f"{self.url}: {_reason(exc)}") from None
        return taken

    async def _get(self, url: str) -> bytes:
        if self._client is None:
            raise TransportError(f"{self.url}: not open")
        try:
            # the whole exchange, head included: a peer may trickle that too
            async with asyncio.timeout(self.deadline), self._client.stream("GET", url) as answer:
                status = answer.status_code
                body = await self._body(answer)
        except TimeoutError:  # the document's deadline (asyncio's, not httpx's)
            raise TransportTimeout(self._late()) from None
        except httpx.TimeoutException:
            raise TransportTimeout(f"{self.url}: no answer from the agent in time") from None
        except httpx.HTTPError as exc:
            raise TransportError(f"{self.url}: {_reason(exc)}") from None
        if status >= 400 and b"MTConnectError" not in body[:4096]:
            raise RemoteProtocolError(f"{self.url}: HTTP {status} from the agent")
        return body

    async def _body(self, answer: httpx.Response) -> bytes:
        """A plain answer's whole body, at most ``max_document`` bytes (the callers bound
        its time)."""
        too_large = f"{self.url}: the agent's answer is larger than {self.max_document} bytes"
        declared = answer.headers.get("content-length", "")
        if declared.isdigit() and int(declared) > self.max_document:
            raise RemoteProtocolError(too_large)
        body = bytearray()
        async for chunk in answer.aiter_bytes():
            body += chunk
            if len(body) > self.max_document:
                raise RemoteProtocolError(too_large)
        return bytes(body)

    def _late(self) -> str:
        return f"{self.url}: the agent's answer did not arrive whole within {self.deadline:g} s"


def _reason(exc: httpx.HTTPError) -> str:
    """The cause's words ("connection refused"), not httpx's wrapping."""
    cause: BaseException | None = exc
    while cause is not None:
        if isinstance(cause, OSError):
            return f"cannot read the agent: {os_reason(cause)}"
        cause = cause.__cause__ or cause.__context__
    return f"cannot read the agent: {exc or type(exc).__name__}"
