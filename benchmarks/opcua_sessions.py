"""What one OPC UA session per control costs the DNC server: CPU per machine (millicores) of the
client's event loop, with one session per machine as in a shop where every control runs its own
OPC UA server (docs/opcua-input.md#cost-per-machine).

N virtual OPC UA servers of one machine each run scripted cycles on a loop in another thread;
N connectors on this thread's loop connect (the CPU per machine of connecting is printed) and
are then read once a second, as the supervisors do, for ``--seconds``: the CPU of this thread
(``time.thread_time``) over the window, per machine. ``--watchdog`` and ``--publishing`` are
the machines' settings; ``--profile`` prints cProfile's heaviest functions of the window.

    .venv/bin/python benchmarks/opcua_sessions.py --machines 20
    .venv/bin/python benchmarks/opcua_sessions.py --machines 20 --watchdog 1 --publishing 0.1
"""

from __future__ import annotations

import argparse
import asyncio
import cProfile
import os
import pstats
import sys
import threading
import time

from opendnc.server.kinds.opcua.connector import OpcuaConnector
from opendnc.server.kinds.opcua.schema import OpcuaMachine
from opendnc.sim.opcua.machine import ScriptedMachineTool, run_cycles
from opendnc.sim.opcua.server import VirtualOpcuaServer


async def _servers(n: int, cycle: float) -> list[VirtualOpcuaServer]:
    servers = []
    for i in range(n):
        server = VirtualOpcuaServer([f"m{i}"])
        await server.start()
        servers.append(server)
        tool = ScriptedMachineTool(server.machines[f"m{i}"])
        length = cycle * (1 + 0.07 * (i % 5))
        asyncio.get_running_loop().create_task(run_cycles(tool, length), name=f"m{i}")
    return servers


async def _measure(args: argparse.Namespace, servers: list[VirtualOpcuaServer]) -> None:
    connectors = [
        OpcuaConnector(
            OpcuaMachine(
                name=f"m{i}",
                endpoint=s.url,
                machine=f"m{i}",
                watchdog=args.watchdog,
                publishing_interval=args.publishing,
            )
        )
        for i, s in enumerate(servers)
    ]
    n = len(connectors)
    c0 = time.thread_time()
    await asyncio.gather(*(c.connect() for c in connectors))
    connect = time.thread_time() - c0
    profile = cProfile.Profile() if args.profile else None
    w0, c1 = time.monotonic(), time.thread_time()
    if profile is not None:
        profile.enable()
    while time.monotonic() - w0 < args.seconds:
        for c in connectors:
            await c.status()  # what a supervisor's poll costs: no request
        await asyncio.sleep(1.0)
    if profile is not None:
        profile.disable()
    cpu, wall = time.thread_time() - c1, time.monotonic() - w0
    notes = sum(c.readings.notifications for c in connectors)
    print(
        f"N={n} watchdog {args.watchdog:g} s, publishing {args.publishing:g} s: connecting "
        f"{1000 * connect / n:.1f} ms CPU per machine; following {1000 * cpu / wall / n:.2f} "
        f"millicores per machine ({notes} notifications)",
        flush=True,
    )
    if profile is not None:
        pstats.Stats(profile).sort_stats("tottime").print_stats(20)


def main() -> None:
    """Start the servers, measure, print one line."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--machines", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--cycle", type=float, default=10.0, help="seconds of a scripted part")
    parser.add_argument("--watchdog", type=float, default=OpcuaMachine.watchdog)
    parser.add_argument("--publishing", type=float, default=OpcuaMachine.publishing_interval)
    parser.add_argument("--profile", action="store_true")
    args = parser.parse_args()
    loop = asyncio.new_event_loop()
    threading.Thread(target=loop.run_forever, daemon=True).start()
    build = asyncio.run_coroutine_threadsafe(_servers(args.machines, args.cycle), loop)
    servers = build.result(900)
    asyncio.run(_measure(args, servers))
    sys.stdout.flush()
    # the servers' loop thread holds sessions and cycles: end the process without waiting
    os._exit(0)


if __name__ == "__main__":
    main()
