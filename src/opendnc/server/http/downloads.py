"""Large downloads streamed from the database in pieces (docs/server.md#bounded-clients).

A program version or a reception was read whole into memory and handed to the connection in
one go: a client that did not read held the whole body in the server (64 MB each, twelve
such clients over a gigabyte). Here the bytes are read :data:`~opendnc.server.http.clients.CHUNK`
at a time, each piece in a short read transaction of its own (SQLite's incremental blob
I/O; PostgreSQL's ``substr`` of the bytea), and only when the connection has taken the piece
before: a client that stops reading holds one piece until the send timeout cuts it
(:class:`opendnc.server.http.clients.SendTimeout`), and no database connection meanwhile.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from sqlalchemy import LargeBinary, func, literal_column, select
from sqlalchemy.orm import Session, sessionmaker
from starlette.responses import StreamingResponse

from opendnc.server.actions.models import Stored
from opendnc.server.core.errors import NotFound
from opendnc.server.http.clients import CHUNK
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
        with reads() as session:
            data = _piece(session, sha256, offset, min(chunk, size - offset))
        if not data:
            raise NotFound(f"content {sha256} ended at byte {offset} of {size}")
        yield data
        offset += len(data)


def _piece(session: Session, sha256: str, offset: int, length: int) -> bytes:
    connection = session.connection()
    if connection.dialect.name == "sqlite":
        # SQLite's substr() reads the whole blob to cut a piece out of it (64 MB for each
        # 256 KiB piece, measured: the server's memory grew by the whole body per client);
        # its incremental blob I/O reads just the piece. The row is found by its rowid.
        rowid = session.scalar(
            select(literal_column("rowid")).select_from(Blob).where(Blob.sha256 == sha256)
        )
        if rowid is None:
            return b""
        raw: Any = connection.connection.driver_connection
        with raw.blobopen("blobs", "data", int(rowid), readonly=True) as blob:
            blob.seek(offset)
            return bytes(blob.read(length))
    # PostgreSQL: substr() of a bytea sends only the piece; the database reads the value up
    # to it (a compressed value is decompressed up to the piece's end).
    piece = func.substr(Blob.data, offset + 1, length, type_=LargeBinary)
    data = session.scalar(select(piece).where(Blob.sha256 == sha256))
    return bytes(data) if data else b""


def stored_response(reads: sessionmaker[Session], stored: Stored) -> StreamingResponse:
    """The bytes of ``stored`` as an ``application/octet-stream`` answer with their length
    and SHA-256, read piece by piece as the client takes them."""
    return StreamingResponse(
        blob_pieces(reads, stored.sha256, stored.size),
        media_type="application/octet-stream",
        headers={"Content-Length": str(stored.size), "X-Content-SHA256": stored.sha256},
    )
