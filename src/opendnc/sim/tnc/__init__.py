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

How the families differ (see ``profiles.py`` for every value)::

    profile         S_PR  R_VR parts  max buffer  attributes  R_RI            R_DP/scope  keys
    tnc640, tnc620  120   5           4096        new         20-26, 30-34    no          new
    tnc320 (v18)    120   5           4088 (wire) new         20-26, 30-34    no          new
    tnc7            120   5           4096        new         20-26, 30-34    no          refused
    itnc530 (PGM)   124   4           4096        old         + 27, 28, 51    yes         new
    tnc426          120   4           1024        old         23-26           no          old
    cncpilot640     120   5           4096        new         21-26, 30-34    no          new
    manualplus620   120   5           2048        new         21-26, 30-34    no          new

Logins: INSPECT, FILE, MONITOR (exclusive), DNC (only with the DNC option), PLCDEBUG,
DIAGNOSTICS without password; FILEPLC/FILESYS/FILELOG/STREAMAXES need the PLC code number
(807667); DATA and OSZI only on the iTNC.  Anything a family lacks is refused with ``T_ER``
(24 unsupported selector/command, 49 login not possible, 22 unknown telegram, 23 missing login).

Driving the machine from a test (on the simulator thread via ``tnc.call``)::

    def run(control):
        control.select_program("TNC:/nc_prog/POCKET.H")
        control.machine.press_key(0x01C3)   # full-sequence mode
        control.machine.start()              # NC start (also key 0x00F0 over C_EK)

Files: ``ROOT/TNC``, ``ROOT/PLC``, ``ROOT/SYS``, ``ROOT/LOG`` hold the drives; uploads in
progress live in ``ROOT/.partial`` and are renamed into place only on ``T_FD``; machine
parameters persist in ``ROOT/.state``.

Event loop: with the optional ``uvloop`` package (``pip install opendnc[sim]``) ``start_tnc``
and ``opendnc sim tnc`` run on uvloop, else on asyncio's loop (:func:`new_event_loop`).
"""

from __future__ import annotations

from opendnc.sim.tnc.control import Control
from opendnc.sim.tnc.profiles import PROFILES, Profile, get_profile
from opendnc.sim.tnc.server import TncHandle, TncServer, new_event_loop, serve_tnc, start_tnc
from opendnc.sim.tnc.trace import TraceHook

__all__ = [
    "PROFILES",
    "Control",
    "Profile",
    "TncHandle",
    "TncServer",
    "TraceHook",
    "get_profile",
    "new_event_loop",
    "serve_tnc",
    "start_tnc",
]
