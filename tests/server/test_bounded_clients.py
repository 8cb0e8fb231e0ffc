"""Bounded clients against a real server (docs/server.md#bounded-clients): a download that
its client does not read is cut after the send timeout, a download streams the stored bytes
whole, event streams are counted per user and in total (503 and Retry-After beyond), and an
idle stream sends heartbeats. The load figures (12 non-reading 64 MB downloads, 1,200 idle
streams) are benchmarks/bounded_clients.py's."""

from __future__ import annotations

import hashlib
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server.config.clients import ClientLimits
from opendnc.server.config.shop import ConfigError, parse_config
from opendnc.server.core.errors import NotFound
from opendnc.server.http.downloads import blob_pieces
from opendnc.server.library import versions as library
from opendnc.server.store.models import Role
from tests.server.harness import wait_for
from tests.server.inprocess_app import App, running

MACHINES: list[dict[str, object]] = [
    {"name": "tnc", "kind": "lsv2", "host": "127.0.0.1", "port": 1, "poll_interval": 0.5},
]
CLIENTS = """[clients]
send_timeout = 1
heartbeat = 1
streams_per_user = 2
streams_total = 3
"""
# 8 MiB: far more than loopback's socket buffers take from a client that reads nothing
BIG = b"G01 X1.234 Y-5.678 F100.\n" * (8 * 1024 * 1024 // 25)


@pytest.fixture(scope="module")
def app(tmp_path_factory: pytest.TempPathFactory) -> Iterator[App]:
    with running(tmp_path_factory.mktemp("bounded"), MACHINES, extra=CLIENTS, check="warn") as a:
        with a.server.sessions.begin() as s:
            library.add_version(s, "BIG.nc", BIG, author="t")
        yield a


def _port(app: App) -> int:
    return int(str(app.client.base_url).rstrip("/").rsplit(":", 1)[1])


def _request(app: App, path: str) -> bytes:
    key = app.api_keys[Role.VIEWER]
    return f"GET {path} HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {key}\r\n\r\n".encode()


def _closed_by_server(sock: socket.socket) -> bool:
    # Asked of the kernel, without reading: a read, however small, would make room for more
    # of the download (the client would be reading after all). 1 is TCP_ESTABLISHED; a
    # server that aborts the connection leaves it CLOSE (a reset), one that closes it
    # CLOSE_WAIT.
    info = sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 8)
    return info[0] != 1


def test_a_client_that_does_not_read_a_download_is_cut_after_the_send_timeout(app: App) -> None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # reads nothing, takes little
    sock.connect(("127.0.0.1", _port(app)))
    try:
        sock.sendall(_request(app, "/api/programs/BIG.nc/versions/1/content"))
        started = time.monotonic()
        time.sleep(0.5)
        assert not _closed_by_server(sock)  # the server waits for it a while
        wait_for("the server to cut the client", lambda: _closed_by_server(sock), timeout=20)
        assert time.monotonic() - started >= 1.0  # not before the send timeout
    finally:
        sock.close()
    assert app.client.get("/api/health").status_code == 200


def test_a_download_streams_the_stored_bytes_whole(app: App) -> None:
    reply = app.client.get("/api/programs/BIG.nc/versions/1/content", headers=app.api(Role.VIEWER))
    assert reply.status_code == 200
    assert reply.content == BIG
    assert reply.headers["content-length"] == str(len(BIG))
    assert reply.headers["x-content-sha256"] == hashlib.sha256(BIG).hexdigest()
    missing = app.client.get(
        "/api/programs/BIG.nc/versions/9/content", headers=app.api(Role.VIEWER)
    )
    assert missing.status_code == 404


def _stream(app: App, role: Role) -> Any:
    return app.client.stream("GET", "/api/events", headers=app.api(role), timeout=10)


def test_streams_beyond_the_user_s_cap_and_the_server_s_are_refused_with_503(app: App) -> None:
    with _stream(app, Role.VIEWER) as one, _stream(app, Role.VIEWER) as two:
        assert (one.status_code, two.status_code) == (200, 200)
        third = app.client.get("/api/events", headers=app.api(Role.VIEWER))
        assert third.status_code == 503
        assert int(third.headers["Retry-After"]) > 0
        assert "viewer has 2 event streams open" in third.json()["detail"]
        with _stream(app, Role.OPERATOR) as other:  # another user: the third of three
            assert other.status_code == 200
            full = app.client.get("/api/events", headers=app.api(Role.ADMIN))
            assert full.status_code == 503
            assert "the server has 3 event streams open" in full.json()["detail"]

    # closed streams give their slots back (the server sees the close shortly after)
    def opens() -> bool:
        with _stream(app, Role.VIEWER) as a, _stream(app, Role.VIEWER) as b:
            return a.status_code == b.status_code == 200

    wait_for("the slots given back", opens, timeout=10)


def test_an_idle_stream_sends_a_heartbeat_every_interval(app: App) -> None:
    # the inbox's list stream: nothing happens in the inbox, so only heartbeats come; a
    # dashboard stream's keep-alive is a named event a page's script sees (a comment it
    # would not), at least every 2 s (docs/dashboard.md#live-overview)
    with app.client.stream(
        "GET", "/events/lists?topic=inbox", headers=app.page(Role.VIEWER), timeout=10
    ) as stream:
        assert stream.status_code == 200
        started = time.monotonic()
        beats = []
        for line in stream.iter_lines():
            assert line != ": keep-alive", "a page cannot see a comment"
            if line == "event: heartbeat":
                beats.append(time.monotonic() - started)
            if len(beats) == 3 or time.monotonic() - started > 20:
                break
    # the first comes with the stream's opening snapshot, the others when it has been quiet
    assert len(beats) == 3, beats
    assert beats[0] < 1.0
    assert 0.5 <= beats[1] - beats[0] <= 2.0 + 1.0
    assert 0.5 <= beats[2] - beats[1] <= 2.0 + 1.0


def test_the_clients_table_is_read_and_its_bad_values_name_the_key(tmp_path: Path) -> None:
    base = f'[library]\npath = "{tmp_path / "lib"}"\n'
    assert parse_config(base, base=tmp_path).clients == ClientLimits()
    read = parse_config(CLIENTS + base, base=tmp_path).clients
    assert (read.send_timeout, read.heartbeat, read.streams_per_user) == (1.0, 1.0, 2)
    for bad, key in [
        ("send_timeout = 0", "clients.send_timeout"),
        ("heartbeat = 0.1", "clients.heartbeat"),
        ('streams_total = "many"', "clients.streams_total"),
        ("streams_per_user = 1.5", "clients.streams_per_user"),
        ("stream_timeout = 3", "clients.stream_timeout"),
    ]:
        with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
            parse_config(f"[clients]\n{bad}\n" + base, base=tmp_path)


def test_a_blob_is_read_in_pieces_on_each_database(sessions: sessionmaker[Session]) -> None:
    data = bytes(range(256)) * 1000 + b"tail"  # every byte value, not a multiple of a piece
    with sessions.begin() as s:
        version, _ = library.add_version(s, "PIECES.nc", data, author="t")
        sha, size = version.sha256, version.size
    pieces = list(blob_pieces(sessions, sha, size, chunk=100_000))
    assert [len(p) for p in pieces] == [100_000, 100_000, 56_004]
    assert b"".join(pieces) == data
    with pytest.raises(NotFound):  # a blob shorter than it says (removed under a download)
        list(blob_pieces(sessions, sha, size + 10, chunk=100_000))
