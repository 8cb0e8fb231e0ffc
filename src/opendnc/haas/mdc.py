"""Haas Machine Data Collection (MDC): a sans-IO codec for Q and E commands.

Both ends use it: the client (:mod:`opendnc.haas.mdc_client`) and the virtual control
(:mod:`opendnc.sim.haas.mdc_server`).

Wire format (see docs/haas.md#mdc):

* request: ``?Q100``, ``?Q600 5223``, ``?E10100 1.5``, ended by a new line (we send CR LF);
* reply payload: ``NAME, value[, value...]``;
* NGC framing: ``>`` payload CR LF; classic (RS-232, Setting 143) framing:
  STX payload ETB CR LF ``>``;
* an unknown command is answered ``UNKNOWN`` by classic controls and with a reply starting
  with ``?`` on NGC; an E write is answered ``!`` (accepted) or ``?`` (refused).

Replies are broadcast to every open connection, so a client matches replies to requests by
their name field (:meth:`MdcConnection.next_event` drops replies meant for someone else).
"""

from __future__ import annotations

import collections
import enum
import math
import re
from dataclasses import dataclass
from typing import ClassVar

from opendnc.errors import LocalProtocolError, PeerClosed, RemoteProtocolError

STX, ETB = b"\x02", b"\x17"
LINE_NOISE = bytes((0x00, 0x11, 0x12, 0x13, 0x14, 0x15, 0x18, 0x1A))
"""Bytes a shared serial line carries besides MDC replies: NUL leader, XON/XOFF, DPRNT's
DC2/DC4, and an XModem receiver's NAK, CAN and SUB. No reply contains them; a serial client
drops them so that they cannot stick to the front of a reply (docs/haas.md#mdc)."""
MAX_LINE = 1024
"""Longest request or reply line accepted; longer input is garbage, not a message."""


class ControlType(enum.Enum):
    """Haas control generation; decides the reply framing."""

    NGC = "ngc"
    CLASSIC = "classic"


# --------------------------------------------------------------------------- requests


@dataclass(frozen=True, slots=True)
class Query:
    """``?Q<code>``: read a machine value (not Q600, see :class:`MacroRead`)."""

    code: int


@dataclass(frozen=True, slots=True)
class MacroRead:
    """``?Q600 <var>``: read macro or system variable ``var``."""

    var: int


@dataclass(frozen=True, slots=True)
class MacroWrite:
    """``?E<var> <value>``: write macro variable ``var`` (machine-changing)."""

    var: int
    value: float


@dataclass(frozen=True, slots=True)
class UnknownRequest:
    """A line the control does not understand (lower case, unknown code, garbage)."""

    text: str


Request = Query | MacroRead | MacroWrite


def format_number(value: float) -> str:
    """Render a float the way MDC replies show it: at least one decimal (``0.0``, ``-2.531``)."""
    if not math.isfinite(value):
        raise LocalProtocolError(f"cannot send {value!r} over MDC")
    text = f"{value:.6f}".rstrip("0")
    text = text + "0" if text.endswith(".") else text
    return "0.0" if text in ("-0.0", "0.0") else text


def encode_request(request: Request, eol: bytes = b"\r\n") -> bytes:
    """Bytes of ``request`` as a client sends it."""
    if isinstance(request, Query):
        if request.code == 600 or not 0 <= request.code <= 999:
            raise LocalProtocolError(f"Q{request.code} is not a plain query")
        text = f"?Q{request.code:03d}"
    elif isinstance(request, MacroRead):
        text = f"?Q600 {request.var}"
    else:
        text = f"?E{request.var} {format_number(request.value)}"
    return text.encode("ascii") + eol


_QUERY = re.compile(r"\?Q(\d{3})(?: +(\d{1,6}))?")
_WRITE = re.compile(r"\?E(\d{1,6}) +([+-]?(?:\d+\.?\d*|\.\d+))")


def parse_request(line: str) -> Request | UnknownRequest:
    """Parse one request line as the control does: upper case only, unknown stays unknown."""
    text = line.strip(" \t")
    if match := _QUERY.fullmatch(text):
        code = int(match.group(1))
        if code == 600:
            if match.group(2) is None:
                return UnknownRequest(text)
            return MacroRead(int(match.group(2)))
        if match.group(2) is not None:
            return UnknownRequest(text)
        return Query(code)
    if match := _WRITE.fullmatch(text):
        return MacroWrite(int(match.group(1)), float(match.group(2)))
    return UnknownRequest(text)


class LineFramer:
    """Cut a stream into lines on CR, LF or CR LF (empty lines are dropped)."""

    def __init__(self, max_line: int = MAX_LINE) -> None:
        self._buf = bytearray()
        self._max = max_line

    def feed(self, data: bytes) -> None:
        """Add bytes; raise :class:`RemoteProtocolError` when a line grows too long."""
        self._buf += data
        if len(self._buf) > self._max and not re.search(rb"[\r\n]", self._buf):
            self._buf.clear()
            raise RemoteProtocolError(f"MDC line longer than {self._max} bytes")

    def next_line(self) -> str | None:
        """Next non-empty line decoded as latin-1, or ``None`` when more bytes are needed."""
        while True:
            match = re.search(rb"\r\n|\r|\n", self._buf)
            if match is None:
                return None
            raw = bytes(self._buf[: match.start()])
            del self._buf[: match.end()]
            if raw.strip():
                return raw.decode("latin-1")


# --------------------------------------------------------------------------- replies


def frame_reply(payload: str, control: ControlType) -> bytes:
    """Wrap a reply payload the way ``control`` sends it."""
    body = payload.encode("latin-1")
    if control is ControlType.NGC:
        return b">" + body + b"\r\n"
    return STX + body + ETB + b"\r\n>"


class ReplyFramer:
    """Cut a reply stream (either framing) into payload strings.

    Leading ``>`` prompts, STX/ETB and surrounding blanks are stripped; CR LF (or a lone CR
    or LF) ends a reply. A ``>`` prompt alone is not a reply. :data:`LINE_NOISE` bytes are
    dropped as they arrive.
    """

    def __init__(self, max_line: int = MAX_LINE) -> None:
        self._lines = LineFramer(max_line)

    def feed(self, data: bytes) -> None:
        """Add received bytes."""
        self._lines.feed(data.translate(None, LINE_NOISE))

    def next_payload(self) -> str | None:
        """Next reply payload, or ``None`` when more bytes are needed."""
        while (line := self._lines.next_line()) is not None:
            payload = line.replace("\x02", "").replace("\x17", "").strip().lstrip(">").strip()
            if payload:
                return payload
        return None


def split_fields(payload: str) -> list[str]:
    """Split ``NAME, v1, v2`` into trimmed fields."""
    return [field.strip() for field in payload.split(",")]


def parse_duration(text: str) -> int:
    """``hhhhh:mm:ss`` to seconds; :class:`RemoteProtocolError` when malformed."""
    match = re.fullmatch(r"(\d{1,7}):([0-5]?\d):([0-5]?\d)", text.strip())
    if match is None:
        raise RemoteProtocolError(f"bad MDC time {text!r}: expected hhhhh:mm:ss")
    hours, minutes, seconds = (int(g) for g in match.groups())
    return hours * 3600 + minutes * 60 + seconds


def format_duration(seconds: float) -> str:
    """Seconds to the ``hhhhh:mm:ss`` form MDC uses."""
    total = max(0, int(seconds))
    return f"{total // 3600:05d}:{total % 3600 // 60:02d}:{total % 60:02d}"


def _int(text: str, what: str) -> int:
    try:
        return int(text.strip())
    except ValueError:
        raise RemoteProtocolError(f"bad {what} {text!r}: expected an integer") from None


def _float(text: str, what: str) -> float:
    try:
        value = float(text.strip())
    except ValueError:
        raise RemoteProtocolError(f"bad {what} {text!r}: expected a number") from None
    if not math.isfinite(value):
        raise RemoteProtocolError(f"bad {what} {text!r}: not a finite number")
    return value


@dataclass(frozen=True, slots=True)
class TextValue:
    """A one-field text reply: Q100 serial, Q101 software, Q102 model."""

    name: str
    value: str

    def to_payload(self) -> str:
        """The reply payload as the control sends it (framing not included)."""
        return f"{self.name}, {self.value}"


@dataclass(frozen=True, slots=True)
class Mode:
    """Q104: the control's mode (``MDI``, ``MEM``, ``ZERO``, ...); classic wraps it in ``()``."""

    NAME: ClassVar[str] = "MODE"
    mode: str
    parenthesized: bool = False

    def to_payload(self) -> str:
        """The reply payload as the control sends it (framing not included)."""
        return f"MODE, ({self.mode})" if self.parenthesized else f"MODE, {self.mode}"


@dataclass(frozen=True, slots=True)
class Count:
    """An integer reply: Q200 tool changes, Q201 tool in use, Q402/Q403 M30 counters."""

    name: str
    value: int

    def to_payload(self) -> str:
        """The reply payload as the control sends it (framing not included)."""
        return f"{self.name}, {self.value}"


@dataclass(frozen=True, slots=True)
class Duration:
    """A ``hhhhh:mm:ss`` reply: Q300, Q301, Q303, Q304 (``seconds`` is the total)."""

    name: str
    seconds: int

    def to_payload(self) -> str:
        """The reply payload as the control sends it (framing not included)."""
        return f"{self.name}, {format_duration(self.seconds)}"


@dataclass(frozen=True, slots=True)
class ProgramStatus:
    """Q500 when not running: ``PROGRAM, O00123, IDLE, PARTS, 380``."""

    NAME: ClassVar[str] = "PROGRAM"
    program: str
    status: str
    parts: int

    def to_payload(self) -> str:
        """The reply payload as the control sends it (framing not included)."""
        return f"PROGRAM, {self.program}, {self.status}, PARTS, {self.parts}"


@dataclass(frozen=True, slots=True)
class Busy:
    """Q500 while a program runs: ``STATUS, BUSY``."""

    NAME: ClassVar[str] = "STATUS"

    def to_payload(self) -> str:
        """The reply payload as the control sends it (framing not included)."""
        return "STATUS, BUSY"


@dataclass(frozen=True, slots=True)
class MacroValue:
    """Q600: ``MACRO, value`` (a three-field ``MACRO, n, value`` is read by its last field)."""

    NAME: ClassVar[str] = "MACRO"
    value: float

    def to_payload(self) -> str:
        """The reply payload as the control sends it (framing not included)."""
        return f"MACRO, {format_number(self.value)}"


@dataclass(frozen=True, slots=True)
class WriteAccepted:
    """``!``: an E write was accepted."""

    def to_payload(self) -> str:
        """The reply payload as the control sends it (framing not included)."""
        return "!"


@dataclass(frozen=True, slots=True)
class Refused:
    """``?...`` (NGC) or ``UNKNOWN`` (classic): command refused or not understood."""

    text: str = "?"

    def to_payload(self) -> str:
        """The reply payload as the control sends it (framing not included)."""
        return self.text


@dataclass(frozen=True, slots=True)
class OtherReply:
    """A well-formed ``NAME, ...`` reply this codec has no type for; kept raw."""

    name: str
    values: tuple[str, ...]

    def to_payload(self) -> str:
        """The reply payload as the control sends it (framing not included)."""
        return ", ".join((self.name, *self.values))


Reply = (
    TextValue
    | Mode
    | Count
    | Duration
    | ProgramStatus
    | Busy
    | MacroValue
    | WriteAccepted
    | Refused
    | OtherReply
)

# Q code -> (reply name, kind). The names are the ones in Haas's NGC table.
QUERIES: dict[int, tuple[str, type[TextValue | Count | Duration | Mode | ProgramStatus]]] = {
    100: ("SERIAL NUMBER", TextValue),
    101: ("SOFTWARE VERSION", TextValue),
    102: ("MODEL", TextValue),
    104: ("MODE", Mode),
    200: ("TOOL CHANGES", Count),
    201: ("USING TOOL", Count),
    300: ("P.O. TIME", Duration),
    301: ("C.S. TIME", Duration),
    303: ("LAST CYCLE", Duration),
    304: ("PREV CYCLE", Duration),
    402: ("M30 #1", Count),
    403: ("M30 #2", Count),
    500: ("PROGRAM", ProgramStatus),
}
_KIND_BY_NAME = {name: kind for name, kind in QUERIES.values()}


def reply_names(request: Request) -> frozenset[str]:
    """Reply names that answer ``request`` (for matching broadcast replies)."""
    if isinstance(request, MacroRead):
        return frozenset({"MACRO"})
    if isinstance(request, MacroWrite):
        return frozenset({"!"})
    name = QUERIES.get(request.code, ("", TextValue))[0]
    return frozenset({name, "STATUS"}) if request.code == 500 else frozenset({name})


def parse_reply(payload: str) -> Reply:
    """Parse a reply payload (framing already removed) into a typed reply."""
    text = payload.strip()
    if not text:
        raise RemoteProtocolError("empty MDC reply")
    if text == "!":
        return WriteAccepted()
    if text.startswith("?") or text.upper() == "UNKNOWN":
        return Refused(text)
    fields = split_fields(text)
    name, values = fields[0].upper(), fields[1:]
    compact = text.replace(" ", "").replace(",", "").upper()
    if compact == "STATUSBUSY":  # also accepts "STATUS BUSY" without the comma
        return Busy()
    if name == "MACRO":
        if not values:
            raise RemoteProtocolError(f"MACRO reply without a value: {text!r}")
        return MacroValue(_float(values[-1], "macro value"))
    kind = _KIND_BY_NAME.get(name)
    if kind is None:
        return OtherReply(fields[0], tuple(values))
    if kind is ProgramStatus:
        if len(values) < 4:
            raise RemoteProtocolError(f"Q500 reply needs 5 fields: {text!r}")
        return ProgramStatus(values[0], values[1], _int(values[3], "part count"))
    if len(values) < 1:
        raise RemoteProtocolError(f"{name} reply without a value: {text!r}")
    value = values[-1]
    if kind is TextValue:
        return TextValue(name, value)
    if kind is Mode:
        inner = value.strip()
        if inner.startswith("(") and inner.endswith(")"):
            return Mode(inner[1:-1].strip(), parenthesized=True)
        return Mode(inner)
    if kind is Count:
        return Count(name, _int(value, name))
    return Duration(name, parse_duration(value))


def reply_name(reply: Reply) -> str:
    """The name field a reply carries (``!`` / ``?`` for write acks and refusals)."""
    if isinstance(reply, TextValue | Count | Duration | OtherReply):
        return reply.name
    if isinstance(reply, WriteAccepted):
        return "!"
    if isinstance(reply, Refused):
        return "?"
    return reply.NAME


class MdcConnection:
    """Client-side MDC engine: encodes requests and matches broadcast replies to them.

    A reply whose name does not answer the outstanding request (another client's answer) is
    counted in :attr:`foreign` and skipped. ``?``/``UNKNOWN`` always answers the request.
    """

    def __init__(self, eol: bytes = b"\r\n") -> None:
        self._framer = ReplyFramer()
        self._eol = eol
        self._pending: Request | None = None
        self._eof = False
        self.foreign: collections.deque[Reply] = collections.deque(maxlen=100)
        """Replies seen that answered other clients' requests (kept for inspection)."""

    @property
    def pending(self) -> Request | None:
        """The request waiting for its reply, if any."""
        return self._pending

    def send(self, request: Request) -> bytes:
        """Bytes for ``request``; one request at a time."""
        if self._pending is not None:
            raise LocalProtocolError(f"still waiting for the reply to {self._pending}")
        data = encode_request(request, self._eol)
        # Replies that arrived before this request answer someone else's (broadcast).
        while (payload := self._framer.next_payload()) is not None:
            self.foreign.append(parse_reply(payload))
        self._pending = request
        return data

    def receive_data(self, data: bytes) -> None:
        """Feed received bytes; ``b""`` means the peer closed."""
        if not data:
            self._eof = True
        self._framer.feed(data)

    def next_event(self) -> Reply | None:
        """The reply to the pending request, or ``None`` when more bytes are needed."""
        while (payload := self._framer.next_payload()) is not None:
            reply = parse_reply(payload)
            if self._pending is None:
                self.foreign.append(reply)
                continue
            names = reply_names(self._pending)
            if isinstance(reply, Refused) or reply_name(reply) in names:
                self._pending = None
                return reply
            self.foreign.append(reply)
        if self._eof and self._pending is not None:
            raise PeerClosed("the control closed the MDC connection before replying")
        return None

    def reset(self) -> None:
        """Forget the pending request (after a timeout, before a retry)."""
        self._pending = None
