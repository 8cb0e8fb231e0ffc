"""The alerts tests' real peers on loopback: an SMTP server (aiosmtpd, optionally with
STARTTLS and a login) and an HTTP receiver for webhooks (the standard library's server)."""

from __future__ import annotations

import email
import email.policy
import json
import subprocess
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from email.message import EmailMessage
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from tests.peers import require_command, require_module
from tests.server.harness import free_port

require_module("aiosmtpd")

from aiosmtpd.controller import Controller  # noqa: E402
from aiosmtpd.smtp import AuthResult, LoginPassword  # noqa: E402


@dataclass
class Mail:
    """One message the SMTP server took: envelope, parsed message, who logged in."""

    sender: str
    recipients: list[str]
    message: EmailMessage
    login: str | None

    @property
    def subject(self) -> str:
        # a long subject is folded right after "Subject:"; unfolded, its leading space goes
        return str(self.message["Subject"]).strip()

    @property
    def text(self) -> str:
        body = self.message.get_body(("plain",))
        assert body is not None
        return str(body.get_content()).replace("\r\n", "\n")  # type: ignore[attr-defined]


@dataclass
class SmtpPeer:
    """A running aiosmtpd server: its port and the mail it took (thread-safe)."""

    port: int
    mail: list[Mail] = field(default_factory=list)
    logins: list[tuple[str, str]] = field(default_factory=list)  # (user, password) tried
    lock: threading.Lock = field(default_factory=threading.Lock)

    def taken(self) -> list[Mail]:
        with self.lock:
            return list(self.mail)


class _Handler:
    def __init__(self, peer: SmtpPeer) -> None:
        self.peer = peer

    async def handle_DATA(self, server: Any, session: Any, envelope: Any) -> str:
        parsed = email.message_from_bytes(envelope.content, policy=email.policy.default)
        assert isinstance(parsed, EmailMessage)
        login = session.auth_data.login.decode() if session.authenticated else None
        with self.peer.lock:
            self.peer.mail.append(Mail(envelope.mail_from, list(envelope.rcpt_tos), parsed, login))
        return "250 OK"


@contextmanager
def smtp_server(
    *,
    tls: tuple[Path, Path] | None = None,
    users: dict[str, str] | None = None,
    implicit: bool = False,
) -> Iterator[SmtpPeer]:
    """An SMTP server on 127.0.0.1; with ``tls`` (cert, key) it offers STARTTLS and requires
    it (or, ``implicit``, speaks TLS from the start), with ``users`` it requires a login
    (only after STARTTLS)."""
    import ssl

    peer = SmtpPeer(free_port())
    options: dict[str, Any] = {}
    if tls is not None:
        context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        context.load_cert_chain(str(tls[0]), str(tls[1]))
        if implicit:
            options.update(ssl_context=context)
        else:
            options.update(tls_context=context, require_starttls=True)
    if users is not None:

        def check(server: Any, session: Any, envelope: Any, mechanism: str, data: Any) -> Any:
            if not isinstance(data, LoginPassword):
                return AuthResult(success=False, handled=False)
            user, password = data.login.decode(), data.password.decode()
            with peer.lock:
                peer.logins.append((user, password))
            if users.get(user) != password:
                return AuthResult(success=False, handled=False)  # aiosmtpd answers 535
            return AuthResult(success=True, auth_data=data)

        options.update(authenticator=check, auth_require_tls=tls is not None, auth_required=True)
    controller = Controller(_Handler(peer), hostname="127.0.0.1", port=peer.port, **options)
    controller.start()
    try:
        yield peer
    finally:
        controller.stop()


def self_signed(folder: Path) -> tuple[Path, Path]:
    """A certificate for 127.0.0.1 (its own CA) and its key, made by openssl."""
    openssl = require_command("openssl")
    cert, key = folder / "smtp-cert.pem", folder / "smtp-key.pem"
    subprocess.run(
        [openssl, "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1",
         "-nodes", "-keyout", str(key), "-out", str(cert), "-days", "2", "-subj", "/CN=127.0.0.1",
         "-addext", "subjectAltName=IP:127.0.0.1"],
        check=True,
        capture_output=True,
    )  # fmt: skip
    return cert, key


@dataclass
class Post:
    """One request the webhook receiver took."""

    path: str
    headers: dict[str, str]
    body: bytes

    def json(self) -> Any:
        return json.loads(self.body)


@dataclass
class WebhookPeer:
    """A running HTTP receiver: its URL, the posts it took, how many to answer 500."""

    url: str
    posts: list[Post] = field(default_factory=list)
    fail_next: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)

    def taken(self) -> list[Post]:
        with self.lock:
            return list(self.posts)


@contextmanager
def webhook_receiver() -> Iterator[WebhookPeer]:
    """An HTTP server on 127.0.0.1 that keeps every POST (and answers 204, or 500 while
    ``fail_next`` counts down)."""
    holder: list[WebhookPeer] = []

    class Handler(BaseHTTPRequestHandler):
        def do_POST(self) -> None:
            length = int(self.headers.get("Content-Length", "0"))
            body = self.rfile.read(length)
            peer = holder[0]
            with peer.lock:
                peer.posts.append(
                    Post(self.path, {k.lower(): v for k, v in self.headers.items()}, body)
                )
                failing = peer.fail_next > 0
                peer.fail_next -= 1 if failing else 0
            self.send_response(500 if failing else 204)
            self.send_header("Content-Length", "0")
            self.end_headers()

        def log_message(self, format: str, *args: Any) -> None:
            return None

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    holder.append(WebhookPeer(f"http://127.0.0.1:{server.server_address[1]}/hook"))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield holder[0]
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)
