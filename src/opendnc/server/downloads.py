"""Large downloads streamed from the database in pieces (docs/server.md#bounded-clients).

A program version or a reception was read whole into memory and handed to the connection in
one go: a client that did not read held the whole body in the server (64 MB each, twelve
such clients over a gigabyte). Here the bytes are read :data:`~opendnc.server.clients.CHUNK`
at a time, each piece in a short read transaction of its own (``substr`` of the blob, which
SQLite and PostgreSQL both take by byte offset), and only when the connection has taken the
piece before: a client that stops reading holds one piece until the send timeout cuts it
(:class:`opendnc.server.clients.SendTimeout`), and no database connection meanwhile.
"""

from __future__ import annotations

from collections.abc import Iterator

from sqlalchemy import LargeBinary, func, select
from sqlalchemy.orm import Session, sessionmaker
from starlette.responses import StreamingResponse

from opendnc.server.actions.models import Stored
from opendnc.server.clients import CHUNK
from opendnc.server.errors import NotFound
from opendnc.server.store.models import Blob

__all__ = ["blob_pieces", "stored_response"]


def blob_pieces(
    reads: sessionmaker[Session], sha256: str, size: int, chunk: int = CHUNK
) -> Iterator[bytes]:
    """The bytes of blob ``sha256`` (``size`` of them), ``chunk`` at a time, each read in a
    transaction of its own. :class:`NotFound` if the blob is gone or shorter (blobs never
    change, so that is a blob removed under a download: the connection is cut short)."""
    offset = 0
    while offset < size:
        piece = func.substr(Blob.data, offset + 1, min(chunk, size - offset), type_=LargeBinary)
        with reads() as session:
            data = session.scalar(select(piece).where(Blob.sha256 == sha256))
        if not data:
            raise NotFound(f"content {sha256} ended at byte {offset} of {size}")
        yield bytes(data)
        offset += len(data)


def stored_response(reads: sessionmaker[Session], stored: Stored) -> StreamingResponse:
    """The bytes of ``stored`` as an ``application/octet-stream`` answer with their length
    and SHA-256, read piece by piece as the client takes them."""
    return StreamingResponse(
        blob_pieces(reads, stored.sha256, stored.size),
        media_type="application/octet-stream",
        headers={"Content-Length": str(stored.size), "X-Content-SHA256": stored.sha256},
    )
