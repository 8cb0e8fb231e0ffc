"""The dashboard's shop overview with many machines: first render and live updates.

``opendnc sim fleet`` starts N controls (half virtual TNCs, half virtual Haas NGCs) and
writes the configuration; ``opendnc serve`` runs them. Once every machine is online:

- server render: ``GET /`` with a session cookie, timed from the request to the last byte
  (best and median of several), and the page's size;
- browser first render (Chromium through Playwright, when installed): from navigation until
  every card is in the page and the live stream is connected;
- live updates: one released program is sent to every machine at once, so every card shows
  progress; over the window the benchmark counts card updates swapped into the page, the
  longest gap between two swaps while jobs ran, and the browser's long tasks (main thread
  blocked over 50 ms, what a person feels as a stall). The raw event stream is read at the
  same time for its flush rhythm (gaps between messages, the longest until the last
  transfer ended), and the server's event-loop stalls in the window (/api/health/loop).

Target (the dashboard issue): 200 machines, first render under 1 s, updates without stalls.

    .venv/bin/python benchmarks/dashboard.py                 # N = 200
    .venv/bin/python benchmarks/dashboard.py --size 40 --seconds 10
"""

from __future__ import annotations

import argparse
import http.client
import itertools
import json
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
import urllib.request
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fleet import _cli, _free_port, _get, _stop, stalls
from headless_chromium import CHROMIUM, CHROMIUM_ARGS

PASSWORD = "bench-password-1"
PROGRAM = (
    b"%\r\nO04000 (BENCH)\r\nG20\r\n"
    + b"".join(
        f"G01 X{i % 97 / 10:.4f} Y{i % 89 / 10:.4f} F40.\r\n".encode() for i in range(20_000)
    )
    + b"M30\r\n%\r\n"
)


def _request(method: str, url: str, key: str, body: Any = None, raw: bytes | None = None) -> Any:
    data = raw if raw is not None else (json.dumps(body).encode() if body is not None else None)
    headers = {"Authorization": f"Bearer {key}"}
    if body is not None:
        headers["Content-Type"] = "application/json"
    request = urllib.request.Request(url, data=data, method=method, headers=headers)
    with urllib.request.urlopen(request, timeout=60) as reply:
        return json.load(reply)


def _login(host: str, port: int) -> str:
    conn = http.client.HTTPConnection(host, port, timeout=30)
    # the login form's CSRF token and the cookie it must match (docs/server.md#throttling)
    conn.request("GET", "/login")
    page = conn.getresponse()
    token = re.search(r'name="csrf" value="([^"]+)"', page.read().decode())
    login_cookie = (page.getheader("Set-Cookie") or "").split(";", 1)[0]
    if token is None or not login_cookie:
        raise SystemExit("the login page carries no CSRF token")
    form = urllib.parse.urlencode(
        {"username": "admin", "password": PASSWORD, "next": "/", "csrf": token.group(1)}
    )
    headers = {"Content-Type": "application/x-www-form-urlencoded", "Cookie": login_cookie}
    conn.request("POST", "/login", form, headers)
    reply = conn.getresponse()
    reply.read()
    cookie = reply.getheader("Set-Cookie") or ""
    if reply.status != 303 or not cookie:
        raise SystemExit(f"login failed: {reply.status}")
    return cookie.split(";", 1)[0]


def _server_render(host: str, port: int, cookie: str, times: int = 7) -> tuple[float, float, int]:
    spent: list[float] = []
    size = 0
    for _ in range(times):
        conn = http.client.HTTPConnection(host, port, timeout=30)
        t0 = time.perf_counter()
        conn.request("GET", "/", headers={"Cookie": cookie})
        body = conn.getresponse().read()
        spent.append(time.perf_counter() - t0)
        size = len(body)
        conn.close()
    return min(spent), statistics.median(spent), size


def _read_stream(host: str, port: int, cookie: str, seconds: float, out: dict[str, Any]) -> None:
    """Read the raw event stream: when messages arrive and how many card events they hold."""
    conn = http.client.HTTPConnection(host, port, timeout=seconds + 30)
    conn.request("GET", "/events/cards", headers={"Cookie": cookie})
    reply = conn.getresponse()
    arrivals: list[float] = []
    sending: list[bool] = []  # whether the chunk showed a card with a running transfer
    events = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        chunk = reply.read1(65536)
        if not chunk:
            break
        # a card of its own (event card-NAME) or one in a batch (out-of-band swap)
        count = chunk.count(b"event: card-") + chunk.count(b'hx-swap-oob="innerHTML"')
        # keep-alives say nothing about updates, and a big message comes in several reads:
        # a message starts with its event line
        if b"event: card" in chunk:
            arrivals.append(time.monotonic())
            sending.append(b"<progress" in chunk)
        elif sending and b"<progress" in chunk:
            sending[-1] = True
        events += count
    conn.close()
    gaps = [b - a for a, b in itertools.pairwise(arrivals)]
    # From the send until the chunk after the last one that showed a transfer, every flush
    # (CARD_INTERVAL) has news (queue lengths, jobs starting, progress): a longer gap there
    # is a stall of the stream, not a quiet shop.
    last = max((i for i, shown in enumerate(sending) if shown), default=-1)
    busy = gaps[: last + 1]
    out.update(
        chunks=len(arrivals),
        events=events,
        gap_max=max(gaps, default=0.0),
        sending_chunks=sum(sending),
        sending_gap_max=max(busy, default=0.0),
        sending_gaps=sorted(busy),
    )


def _load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def _browser(url: str, cookie: str, n: int, send: Any, seconds: float) -> dict[str, Any] | None:
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        return None
    name, value = cookie.split("=", 1)
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        ctx = browser.new_context(viewport={"width": 1280, "height": 800})
        ctx.add_cookies([{"name": name, "value": value, "url": url}])
        page = ctx.new_page()
        page.add_init_script(
            """
            window.bench = {long: [], swaps: [], messages: 0};
            new PerformanceObserver(l => l.getEntries().forEach(
                e => window.bench.long.push(e.duration))).observe({type: 'longtask'});
            // cards swapped in: out of band from a batched message, or a message of their own;
            // and how long swapping one message took: from the first listener of the message
            // (capture on window) to the last one after the swap (bubble on window: of
            // sseBeforeMessage when the page's script swapped, of sseMessage when htmx did)
            window.bench.busy = [];
            let t0 = 0, cards = 0;
            window.addEventListener('htmx:sseBeforeMessage', e => {
                window.bench.messages++;
                const d = e.detail || {};
                cards = d.type && d.type.startsWith('card-') ? 1
                    : ((d.data || '').match(/hx-swap-oob="innerHTML"/g) || []).length;
                t0 = performance.now();
                for (let i = 0; i < cards; i++) window.bench.swaps.push(t0);
            }, true);
            const done = () => {
                if (cards) window.bench.busy.push([cards, performance.now() - t0]);
            };
            window.addEventListener('htmx:sseBeforeMessage', e => {
                if (e.defaultPrevented) done();
            });
            window.addEventListener('htmx:sseMessage', done);
            """
        )
        t0 = time.perf_counter()
        page.goto(url + "/")
        page.wait_for_function(f"document.querySelectorAll('.card').length === {n}")
        first = time.perf_counter() - t0
        page.wait_for_function("window.bench.messages > 0", timeout=30_000)  # connected
        ready = time.perf_counter() - t0
        page.evaluate(
            "window.bench.long = []; window.bench.swaps = []; window.bench.messages = 0;"
            "window.bench.busy = []"
        )
        send()
        page.wait_for_timeout(seconds * 1000)
        bench = page.evaluate("window.bench")
        running = page.evaluate("document.querySelectorAll('.card progress').length")
        browser.close()
    swaps = bench["swaps"]
    gaps = [(b - a) / 1000 for a, b in itertools.pairwise(swaps)]
    return {
        "first_render": first,
        "live_ready": ready,
        "swaps": len(swaps),
        "messages": bench["messages"],
        "busy": max(bench["busy"], key=lambda b: b[1], default=[0, 0.0]),
        "swap_gap_max": max(gaps, default=0.0),
        "long_tasks": len(bench["long"]),
        "long_max_ms": max(bench["long"], default=0.0),
        "still_running": running,
    }


def run(n: int, seconds: float, poll: float, folder: Path) -> None:
    """Measure one fleet size and print the figures."""
    from opendnc.server.access import auth
    from opendnc.server.store.db import make_engine, make_sessions, migrate
    from opendnc.server.store.models import Role

    config = folder / "fleet.toml"
    port = _free_port()
    fleet = _cli(
        "sim", "fleet", "--tnc", str(n // 2), "--haas", str(n - n // 2),
        "--config-out", str(config), "--bind", f"127.0.0.1:{port}", "--poll", str(poll),
        "--root", str(folder / "machines"),
    )  # fmt: skip
    server = None
    try:
        deadline = time.monotonic() + 180
        while not config.exists():
            if fleet.poll() is not None or time.monotonic() > deadline:
                raise SystemExit("the fleet did not start")
            time.sleep(0.1)
        db = f"sqlite:///{folder / 'dashboard.db'}"
        engine = make_engine(db)
        migrate(engine)
        with make_sessions(engine).begin() as session:
            auth.create_user(session, "admin", Role.ADMIN, password=PASSWORD)
            _, key = auth.create_key(session, "admin", Role.ADMIN)
        engine.dispose()
        log = (folder / "server.log").open("wb")
        command = ["serve", "--config", str(config), "--db", db]
        server = subprocess.Popen(
            [sys.executable, "-m", "opendnc.cli.main", *command],
            start_new_session=True,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        base = f"http://127.0.0.1:{port}"
        while True:
            try:
                machines = _get(base + "/api/machines", key)
                if len(machines) == n and all(m["online"] and m["status"] for m in machines):
                    break
            except OSError:
                pass
            if server.poll() is not None or time.monotonic() > deadline:
                raise SystemExit("the machines did not come online")
            time.sleep(0.5)
        _request("PUT", base + "/api/programs/O04000.nc", key, raw=PROGRAM)
        _request("POST", base + "/api/programs/O04000.nc/versions/1/release", key)
        cookie = _login("127.0.0.1", port)
        best, median, size = _server_render("127.0.0.1", port, cookie)
        print(f"N={n}: server render of / best {best * 1000:.0f} ms, median "
              f"{median * 1000:.0f} ms, {size / 1000:.0f} kB of HTML", flush=True)  # fmt: skip
        names = [m["name"] for m in machines]
        stream: dict[str, Any] = {}
        reader = threading.Thread(
            target=_read_stream, args=("127.0.0.1", port, cookie, seconds + 5, stream)
        )

        def send() -> None:
            reader.start()
            try:
                _request(
                    "POST", base + "/api/jobs", key, {"program": "O04000.nc", "machines": names}
                )
            except OSError as exc:
                tail = (folder / "server.log").read_text(errors="replace")[-3000:]
                raise SystemExit(f"queueing the sends failed: {exc}\n{tail}") from None

        print(f"  load average before the window: {_load()}", flush=True)
        window_start = time.time()
        figures = _browser(base, cookie, n, send, seconds)
        if figures is None:
            send()
            print("  (playwright not installed: no browser figures)")
        else:
            print(
                f"  browser: all {n} cards after {figures['first_render'] * 1000:.0f} ms, "
                f"live after {figures['live_ready'] * 1000:.0f} ms",
                flush=True,
            )
            print(
                f"  sending to all {n} machines for {seconds:.0f} s: {figures['swaps']} card "
                f"updates swapped in from {figures['messages']} messages, "
                f"longest gap {figures['swap_gap_max'] * 1000:.0f} ms, "
                f"{figures['long_tasks']} long tasks (longest {figures['long_max_ms']:.0f} ms), "
                f"{figures['still_running']} cards still sending at the end",
                flush=True,
            )
            cards, busy = figures["busy"]
            print(f"  slowest message to swap: {busy:.0f} ms for {cards} cards", flush=True)
        reader.join()
        print(
            f"  event stream: {stream.get('events', 0)} card events in "
            f"{stream.get('chunks', 0)} messages, longest gap between them "
            f"{stream.get('gap_max', 0) * 1000:.0f} ms",
            flush=True,
        )
        if stream.get("sending_chunks"):
            gaps = stream["sending_gaps"]
            print(
                f"  until the last transfer ended: {len(gaps) + 1} messages, gap between two "
                f"median {statistics.median(gaps or [0]) * 1000:.0f} ms, longest "
                f"{stream['sending_gap_max'] * 1000:.0f} ms",
                flush=True,
            )
        seen = stalls(base, window_start)
        longest = seen[0] if seen else None
        if longest is None:
            print("  server event loop: no stall of 50 ms or more in the window", flush=True)
        else:
            wait = "?" if longest["wait"] is None else f"{longest['wait'] * 1000:.0f} ms"
            total = sum(s["seconds"] for s in seen)
            print(
                f"  server event loop: {len(seen)} stalls of 50 ms or more, "
                f"{total:.2f} s in all; longest {longest['seconds'] * 1000:.0f} ms "
                f"(its thread ran {longest['run'] * 1000:.0f} ms, waited for a CPU {wait})",
                flush=True,
            )
        print(f"  load average after the window: {_load()}", flush=True)
        done = [j for j in _get(base + "/api/jobs?limit=1000", key) if j["state"] == "done"]
        print(f"  jobs done by then: {len(done)} of {n}", flush=True)
    finally:
        if server is not None:
            _stop(server)
        _stop(fleet)


def main() -> None:
    """Run one fleet size."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=200, help="machines in the fleet")
    parser.add_argument("--seconds", type=float, default=20.0, help="live window")
    parser.add_argument("--poll", type=float, default=1.0, help="status poll interval (s)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="opendnc-dashboard-bench-") as tmp:
        run(args.size, args.seconds, args.poll, Path(tmp))


if __name__ == "__main__":
    main()
