"""The parts of an agent's streaming answer: sans-IO, fed the body's bytes as they come.

A ``sample`` or ``current`` request with ``interval`` is answered with one endless
``multipart/mixed`` (older agents: ``multipart/x-mixed-replace``) body; each part is
``--BOUNDARY``, its header lines, an empty line, then exactly ``Content-length`` bytes of
document (docs/mtconnect-input.md#streaming). The splitter reads the length rather than
searching for the next boundary, so a document may hold any bytes.
"""

from __future__ import annotations

import re

from opendnc.errors import RemoteProtocolError

__all__ = ["MAX_HEADERS", "MultipartSplitter", "boundary_of"]

MAX_HEADERS = 4096
"""The most bytes a part's header lines may take: an agent sends two short lines."""

_BOUNDARY = re.compile(r'boundary\s*=\s*"?([^";\s]+)"?', re.IGNORECASE)


def boundary_of(content_type: str) -> str | None:
    """The boundary of a ``multipart/...`` content type; None when it is no multipart."""
    if not content_type.lower().lstrip().startswith("multipart/"):
        return None
    match = _BOUNDARY.search(content_type)
    if match is None:
        raise RemoteProtocolError(f"multipart answer without a boundary: {content_type[:80]!r}")
    return match.group(1)


class MultipartSplitter:
    """Cuts a multipart body into its parts' documents.

    :meth:`feed` takes any slice of the body and returns the documents it completed;
    :attr:`closed` turns true at the closing ``--BOUNDARY--``.
    """

    def __init__(self, boundary: str, *, max_part: int = 16 * 1024 * 1024) -> None:
        if not boundary:
            raise RemoteProtocolError("multipart boundary is empty")
        self._delimiter = b"--" + boundary.encode("latin-1")
        self._max_part = max_part
        self._buffer = bytearray()
        self._length: int | None = None  # the body length of the part being read
        self.closed = False

    def feed(self, data: bytes) -> list[bytes]:
        """Take more of the body; the documents completed by it, in order."""
        if self.closed:
            return []
        self._buffer += data
        parts: list[bytes] = []
        while not self.closed:
            if self._length is None and not self._headers():
                break
            if self._length is None or len(self._buffer) < self._length:
                break
            parts.append(bytes(self._buffer[: self._length]))
            del self._buffer[: self._length]
            self._length = None
        return parts

    def _headers(self) -> bool:
        """Read up to the end of the next part's headers; False when more bytes are needed."""
        buffer = self._buffer
        # the CR LF ending the last part's document (and any blank lines) come first
        start = 0
        while buffer[start : start + 2] == b"\r\n" or buffer[start : start + 1] == b"\n":
            start += 2 if buffer[start : start + 1] == b"\r" else 1
        if len(buffer) - start < len(self._delimiter) + 2:
            del buffer[:start]
            return False
        if not buffer.startswith(self._delimiter, start):
            raise RemoteProtocolError(
                f"multipart: expected the boundary, got {bytes(buffer[start : start + 40])!r}"
            )
        after = start + len(self._delimiter)
        if buffer[after : after + 2] == b"--":
            self.closed = True
            buffer.clear()
            return False
        end = buffer.find(b"\r\n\r\n", after)
        if end < 0:
            if len(buffer) - start > MAX_HEADERS:
                raise RemoteProtocolError("multipart: part headers longer than 4096 bytes")
            del buffer[:start]
            return False
        if end - start > MAX_HEADERS:
            raise RemoteProtocolError("multipart: part headers longer than 4096 bytes")
        length = None
        for line in bytes(buffer[after:end]).split(b"\r\n"):
            name, _, value = line.partition(b":")
            if name.strip().lower() == b"content-length":
                try:
                    length = int(value.strip())
                except ValueError:
                    raise RemoteProtocolError(
                        f"multipart: Content-length {value.strip()[:20]!r} is not a number"
                    ) from None
        if length is None:
            raise RemoteProtocolError("multipart: a part without Content-length")
        if not 0 <= length <= self._max_part:
            raise RemoteProtocolError(f"multipart: part of {length} bytes is out of bounds")
        del buffer[: end + 4]
        self._length = length
        return True
