"""Virtual TNC: an LSV2 server that answers like a Heidenhain programming station.

Blocking code and tests (the simulator runs on its own event loop in a thread)::

    from opendnc.sim.tnc import start_tnc

    with start_tnc("tnc640", root=tmp_path) as tnc:      # root=None: temporary folder
        client = SomeLsv2Client("127.0.0.1", tnc.port)
        ...
        state = tnc.call(lambda control: control.machine.program_state)

asyncio code::

    from opendnc.sim.tnc import serve_tnc

    server = await serve_tnc("itnc530", root="/srv/tnc", port=0)
    print(server.port)
    ...
    await server.close()

Profiles (``PROFILES``): tnc640, tnc620, tnc320, tnc7, itnc530, tnc426, cncpilot640,
manualplus620.  Options of both entry points: ``host``, ``port`` (0 = any free port, read
back from ``.port``), ``latency`` (seconds per telegram), ``trace`` (a :class:`TraceHook`),
``dnc_option`` (False refuses the DNC login as a machine without the option does).

Driving the machine from a test (on the simulator thread via ``tnc.call``)::

    def run(control):
        control.select_program("TNC:/nc_prog/POCKET.H")
        control.machine.press_key(0x01C3)   # full-sequence mode
        control.machine.start()              # NC start (also key 0x00F0 over C_EK)

Files: ``ROOT/TNC``, ``ROOT/PLC``, ``ROOT/SYS``, ``ROOT/LOG`` hold the drives; uploads in
progress live in ``ROOT/.partial`` and are renamed into place only on ``T_FD``; machine
parameters persist in ``ROOT/.state``.
"""

from __future__ import annotations

from opendnc.sim.tnc.control import Control
from opendnc.sim.tnc.profiles import PROFILES, Profile, get_profile
from opendnc.sim.tnc.server import TncHandle, TncServer, serve_tnc, start_tnc
from opendnc.sim.tnc.trace import TraceHook

__all__ = [
    "PROFILES",
    "Control",
    "Profile",
    "TncHandle",
    "TncServer",
    "TraceHook",
    "get_profile",
    "serve_tnc",
    "start_tnc",
]
