"""`opendnc wait`: wait until servers listen or files exist (for scripts and the README).

A line that starts a server or simulator in the background (``... &``) returns at once; the
next command must not run before the server listens. ``opendnc wait TARGET...`` returns when
every target is ready, and fails with one line naming the first that is not:

* ``tcp://HOST:PORT`` -- a TCP connection is accepted;
* ``http://...`` or ``https://...`` -- a GET is answered with a 2xx status;
* anything else is a path -- it exists (a virtual cable's device link, a ``--ready-file``).
"""

from __future__ import annotations

import os
import socket
import time
import urllib.error
import urllib.request
from dataclasses import dataclass
from urllib.parse import urlsplit

import typer

from opendnc.cli.common import cli_errors
from opendnc.errors import InputError, TransportTimeout

POLL_FIRST = 0.05  # seconds between tries, growing to POLL_MAX
POLL_MAX = 0.5


@dataclass(frozen=True, slots=True)
class Target:
    """One thing to wait for: ``kind`` is tcp, http or path."""

    text: str
    kind: str
    host: str = ""
    port: int = 0

    def probe(self, timeout: float) -> str | None:
        """None when ready, else why not (one short phrase)."""
        if self.kind == "path":
            return None if os.path.exists(self.text) else "does not exist"
        if self.kind == "tcp":
            try:
                socket.create_connection((self.host, self.port), timeout=timeout).close()
            except OSError as exc:
                return (exc.strerror or str(exc)).lower()
            return None
        try:
            with urllib.request.urlopen(self.text, timeout=timeout) as answer:
                status = int(answer.status)
        except urllib.error.HTTPError as exc:
            return f"answered {exc.code}"
        except (urllib.error.URLError, OSError) as exc:
            reason = getattr(exc, "reason", exc)
            return (getattr(reason, "strerror", None) or str(reason)).lower()
        return None if 200 <= status < 300 else f"answered {status}"


def parse_target(text: str) -> Target:
    """``tcp://HOST:PORT``, ``http(s)://...`` or a path; :class:`InputError` otherwise."""
    if "://" not in text:
        if not text:
            raise InputError("an empty target: use tcp://HOST:PORT, http://URL or a path")
        return Target(text, "path")
    parts = urlsplit(text)
    if parts.scheme in ("http", "https") and parts.hostname:
        return Target(text, "http")
    if parts.scheme == "tcp":
        try:
            port = parts.port
        except ValueError:
            port = None
        if parts.hostname and port:
            return Target(text, "tcp", parts.hostname, port)
    raise InputError(f"bad target {text!r}: use tcp://HOST:PORT, http://URL or a path")


def wait_for(targets: list[Target], timeout: float) -> None:
    """Return once every target is ready; :class:`TransportTimeout` after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    pause = POLL_FIRST
    for target in targets:
        while True:
            left = deadline - time.monotonic()
            why = target.probe(max(0.05, min(1.0, left)))
            if why is None:
                break
            if time.monotonic() + pause > deadline:
                raise TransportTimeout(f"{target.text} not ready after {timeout:g} s ({why})")
            time.sleep(pause)
            pause = min(POLL_MAX, pause * 2)


def wait(
    targets: list[str] = typer.Argument(
        ..., help="tcp://HOST:PORT (accepts), http(s)://URL (answers 2xx) or a path (exists)."
    ),
    timeout: float = typer.Option(30.0, "--timeout", help="Seconds to wait for all of them."),
) -> None:
    """Wait until servers listen (or files exist); exit 1 naming the first that did not."""
    with cli_errors():
        if not timeout > 0:
            raise InputError(f"bad --timeout {timeout:g}: give seconds above 0")
        wait_for([parse_target(t) for t in targets], timeout)
