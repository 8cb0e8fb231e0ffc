"""A built server (``opendnc.server.app.build``) served by uvicorn in a thread of the test's
process, on a loopback port the system picks: real HTTP in one process."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from tests.peers import require_module

uvicorn = require_module("uvicorn")

from opendnc.cli.serve import listen_socket  # noqa: E402
from tests.server.harness import wait_for  # noqa: E402

# A browser page left open holds an event stream: uvicorn would wait for it for as long as
# the thread join allows (30 s a module, measured). Two seconds, then it closes them.
GRACE_S = 2


@contextmanager
def serving(server: Any, port: int = 0) -> Iterator[str]:
    """Serve ``server.app``; its base URL. The engine is disposed of at the end. ``port``:
    one this test served on before (a server started again where its pages are open)."""
    # bound here with port 0: a port chosen beforehand could be taken meanwhile
    listener = listen_socket("127.0.0.1", port)
    port = listener.getsockname()[1]
    config = uvicorn.Config(
        server.app, log_level="warning", loop="asyncio", timeout_graceful_shutdown=GRACE_S
    )
    web = uvicorn.Server(config)
    thread = threading.Thread(target=web.run, kwargs={"sockets": [listener]}, daemon=True)
    thread.start()
    try:
        wait_for("the server", lambda: web.started, timeout=30)
        yield f"http://127.0.0.1:{port}"
    finally:
        web.should_exit = True
        thread.join(30)
        listener.close()
        server.engine.dispose()
