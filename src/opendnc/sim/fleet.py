"""Many virtual controls in one process: for demos, the server's tests and its benchmark.

Every control runs on the one asyncio loop of the caller: a virtual TNC costs a listening
socket and a small model, a virtual Haas NGC an MDC server and its program memory, so a few
hundred fit in one process. :func:`server_config` writes the DNC server's configuration for
exactly the controls that were started, so ``opendnc serve`` can be pointed at them at once.

A virtual Haas NGC's net share is its own program memory folder: a program the server pushes
to the share is in the control's memory, as on a machine whose share is mounted as a device.
"""

from __future__ import annotations

import asyncio
import hashlib
import importlib
import json
import socket
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from opendnc.errors import InputError
from opendnc.haas.mdc import ControlType
from opendnc.sim.haas.app import SimHaas, SimOptions
from opendnc.sim.haas.control import DprntDestination, HaasConfig
from opendnc.sim.tnc.server import TncServer, serve_tnc

if TYPE_CHECKING:
    from opendnc.sim.cable.link import VirtualCable
    from opendnc.sim.fanuc import VirtualFanuc
    from opendnc.sim.ftp import VirtualFtpFolder
    from opendnc.sim.haas.serial_front import SerialFrontEnd
    from opendnc.sim.mtconnect.agent import VirtualAgent
    from opendnc.sim.mtconnect.machine import ScriptedMachine
    from opendnc.sim.opcua.machine import ScriptedMachineTool
    from opendnc.sim.opcua.server import VirtualOpcuaServer

__all__ = ["Fleet", "FleetMachine", "server_config", "start_fleet"]


@dataclass(frozen=True)
class FleetMachine:
    """One started control: its name, kind, address and folder."""

    name: str
    # "lsv2", "haas_ngc", "haas_serial", "mtconnect", "opcua" or "serial" (a virtual Fanuc),
    # as in the server's configuration
    kind: str
    host: str
    port: int  # 0 for a serial machine
    root: Path
    serial: str = ""  # the PC's end of a virtual cable
    baud: int = 0
    dprnt_port: int = 0  # a Haas NGC's DPRNT port (Setting 263), 0 for none
    device: str = ""  # an MTConnect machine's device name at the fleet's agent, an OPC UA
    # machine's browse name at the fleet's OPC UA server
    ftp_port: int = 0  # the port of its FTP folder (an --ftp machine), 0 for none


@dataclass
class Fleet:
    """The running controls; :meth:`close` stops them all."""

    machines: list[FleetMachine] = field(default_factory=list)
    _tncs: list[TncServer] = field(default_factory=list, repr=False)
    _haas: list[SimHaas] = field(default_factory=list, repr=False)
    _cables: list[VirtualCable] = field(default_factory=list, repr=False)
    serial_ports: dict[str, SerialFrontEnd] = field(default_factory=dict, repr=False)
    """The serial port of each serial Haas, by machine name: ``select("punch:O1000")`` is the
    operator's key press."""
    sims: dict[str, SimHaas] = field(default_factory=dict, repr=False)
    """Every virtual Haas by machine name (its ``control`` holds program memory and state)."""
    fanucs: dict[str, VirtualFanuc] = field(default_factory=dict, repr=False)
    """Every virtual Fanuc by machine name (:class:`opendnc.sim.fanuc.VirtualFanuc`)."""
    agent: VirtualAgent | None = field(default=None, repr=False)
    """The one virtual MTConnect agent of the ``mtconnect`` machines (None without them)."""
    scripted: dict[str, ScriptedMachine] = field(default_factory=dict, repr=False)
    """The scripted machine behind each ``mtconnect`` machine, by machine name."""
    opcua: VirtualOpcuaServer | None = field(default=None, repr=False)
    """The (first) virtual OPC UA server of the ``opcua`` machines (None without them)."""
    opcua_servers: list[VirtualOpcuaServer] = field(default_factory=list, repr=False)
    """Every virtual OPC UA server (one, a gateway; or one per control)."""
    machine_tools: dict[str, ScriptedMachineTool] = field(default_factory=dict, repr=False)
    """The scripted machine tool behind each ``opcua`` machine, by machine name."""
    opcua_started: asyncio.Task[None] | None = field(default=None, repr=False)
    """After :meth:`start_opcua`: the task that builds and starts the OPC UA server (done when
    it listens, or failed with the reason); :attr:`opcua` is set once it listens."""
    _opcua_later: tuple[list[str], str, int, float] | None = field(default=None, repr=False)
    ftp: dict[str, VirtualFtpFolder] = field(default_factory=dict, repr=False)
    """The FTP folder of each ``--ftp`` machine, by machine name."""
    _cycles: list[asyncio.Task[None]] = field(default_factory=list, repr=False)

    def start_opcua(self) -> asyncio.Task[None] | None:
        """Build and start the OPC UA server of a fleet started with ``opcua_later`` in the
        background (:attr:`opcua_started`; None without one). It costs seconds of CPU, most of
        it in a thread: a caller that starts it once it is serving keeps its start-up quick."""
        if self._opcua_later is not None and self.opcua_started is None:
            self.opcua_started = asyncio.create_task(
                _serve_opcua(self, *self._opcua_later), name="opcua"
            )
        return self.opcua_started

    async def close(self) -> None:
        """Stop every control."""
        for folder in self.ftp.values():
            await asyncio.to_thread(folder.close)
        self.ftp.clear()
        for tnc in self._tncs:
            await tnc.close()
        for haas in self._haas:
            await haas.close()
        for fanuc in self.fanucs.values():
            await asyncio.to_thread(fanuc.close)
        self.fanucs.clear()
        for cable in self._cables:
            cable.close()
        if self.opcua_started is not None:
            # a server still being built is abandoned: it never listened, nothing to stop
            self.opcua_started.cancel()
            await asyncio.gather(self.opcua_started, return_exceptions=True)
            self.opcua_started = None
        self._opcua_later = None  # closed: nothing to start any more
        for task in self._cycles:
            task.cancel()
        if self._cycles:
            await asyncio.gather(*self._cycles, return_exceptions=True)
        if self.agent is not None:
            await self.agent.close()
        for served in self.opcua_servers:
            await served.close()
        self.opcua_servers.clear()
        self.opcua = None
        self._cycles.clear()
        self.agent = None
        self._tncs.clear()
        self._haas.clear()
        self._cables.clear()


async def start_fleet(
    root: Path,
    *,
    tnc: int = 2,
    haas: int = 2,
    host: str = "127.0.0.1",
    base_port: int = 0,
    profile: str = "tnc640",
    serial_haas: int = 0,
    baud: int = 115200,
    block_rate: float = 0.0,
    dnc_timeout: float = 10.0,
    receipts: Path | None = None,
    latency: float = 0.0,
    dprnt: bool = False,
    fanuc: int = 0,
    mtconnect: int = 0,
    mtconnect_cycle: float = 30.0,
    opcua: int = 0,
    ftp: int = 0,
    opcua_servers: int = 1,
    opcua_later: bool = False,
) -> Fleet:
    """Start ``tnc`` virtual TNCs, ``haas`` virtual Haas NGCs and ``serial_haas`` virtual Haas
    on virtual RS-232 cables (POSIX only: a cable is a pair of ptys) under ``root``.

    With ``base_port`` 0 every control takes a free port; otherwise the TNCs listen on
    ``base_port``, ``base_port + 1``, ... and the Haas MDC ports follow them. A serial Haas
    is a classic control: it answers XModem, drip-feed and MDC Q-commands (Setting 143 ON)
    on its cable (``auto`` serial mode) and runs at most ``block_rate`` blocks a second
    (0: as fast as it can); a drip-feed that stops for ``dnc_timeout`` seconds raises the
    control's DNC link alarm. With ``dprnt`` each Haas NGC prints its DPRNT lines to a TCP
    port of its own (Setting 263), which :func:`server_config` names as its source.
    ``mtconnect`` machines are devices ``mtc-1``, ... of one virtual MTConnect agent (the
    port after the Haas ones), each running a scripted cycle of ``mtconnect_cycle`` seconds
    (a part each, a feed hold every fifth, an alarm every thirteenth). ``opcua`` machines are
    machine tools ``opc-1``, ... of one virtual OPC UA server (the port after the agent's),
    running the same cycle; with ``opcua_servers`` K they are spread over K servers (K =
    ``opcua``: one server per control, as in a shop where each control runs its own; the
    ports after the agent's). Building a server's address space costs seconds of CPU: with
    ``opcua_later`` the ``opcua`` machines are listed (their port is chosen) but their one
    server is built and started by :meth:`Fleet.start_opcua`, in the background.

    ``receipts``: every program a virtual TNC receives completely is one JSON line in this
    file (machine, path, size, sha256), so a test counts what each control received;
    ``latency``: seconds each virtual TNC takes to answer a telegram (a busy control).
    ``fanuc``: virtual Fanucs (``opendnc.sim.fanuc``, profile fanuc-0i, in READ) on cables of
    their own at ``baud``, 11 bits a character.
    """
    counts = (tnc, haas, serial_haas, fanuc, mtconnect, opcua, ftp)
    if min(counts) < 0 or sum(counts) == 0:
        raise InputError(
            "start at least one control (--tnc N, --haas M, --fanuc F, --mtconnect K, --opcua U,"
            " --ftp P)"
        )
    # the MTConnect machines (and the FTP ones' status) share one agent, the OPC UA machines
    # one server; each FTP machine has a folder of its own
    agent = 1 if mtconnect or ftp else 0
    if opcua and not 1 <= opcua_servers <= opcua:
        raise InputError(f"--opcua-servers {opcua_servers}: expected 1 to --opcua ({opcua})")
    served = min(opcua, opcua_servers)
    ports = tnc + haas + agent + served + ftp
    if base_port and not 0 < base_port <= 65535 - ports:
        raise InputError(f"--base-port {base_port}: the fleet needs {ports} ports above it")
    fleet = Fleet()
    try:
        for i in range(tnc):
            folder = root / f"tnc-{i + 1}"
            port = base_port + i if base_port else 0
            server = await serve_tnc(profile, folder, host, port, latency=latency)
            if receipts is not None:
                server.control.on_received = _receipt(receipts, f"tnc-{i + 1}")
            fleet._tncs.append(server)
            fleet.machines.append(FleetMachine(f"tnc-{i + 1}", "lsv2", host, server.port, folder))
        for j in range(haas):
            folder = root / f"haas-{j + 1}"
            folder.mkdir(parents=True, exist_ok=True)
            port = base_port + tnc + j if base_port else 0
            sim = SimHaas(
                HaasConfig(
                    model="VF-2",
                    serial_number=f"{1000000 + j}",
                    dprnt=DprntDestination.TCP if dprnt else DprntDestination.NONE,
                ),
                folder,
                SimOptions(host=host, mdc_port=port, dprnt_tcp_port=0 if dprnt else None),
            )
            await sim.start()
            fleet._haas.append(sim)
            fleet.sims[f"haas-{j + 1}"] = sim
            assert sim.mdc is not None  # mdc_port was given
            printer = sim.dprnt_tcp.port if sim.dprnt_tcp is not None else 0
            fleet.machines.append(
                FleetMachine(
                    f"haas-{j + 1}", "haas_ngc", host, sim.mdc.port, folder, dprnt_port=printer
                )
            )
        for k in range(serial_haas):
            folder = root / f"haas-serial-{k + 1}"
            await _start_serial_haas(fleet, folder, k, baud, block_rate, dnc_timeout)
        for n in range(fanuc):
            await asyncio.to_thread(_start_fanuc, fleet, root / f"fanuc-{n + 1}", n, baud)
        if mtconnect or ftp:
            port = base_port + tnc + haas if base_port else 0
            await _start_mtconnect(fleet, root, mtconnect, host, port, mtconnect_cycle, ftp)
        if opcua:
            port = base_port + tnc + haas + agent if base_port else 0
            if opcua_later:  # the demo's way: it is usable while the server is being built
                _list_opcua(fleet, root, opcua, host, port, mtconnect_cycle)
            else:
                await _start_opcua(fleet, root, opcua, host, port, mtconnect_cycle, served)
        first_ftp = base_port + tnc + haas + agent + served if base_port else 0
        for n in range(ftp):
            await _start_ftp(fleet, root, n, host, first_ftp + n if first_ftp else 0)
    except BaseException:
        await fleet.close()
        raise
    return fleet


def _receipt(path: Path, machine: str) -> Callable[[str, Path], None]:
    def note(target: str, host: Path) -> None:
        data = host.read_bytes()
        line = {
            "machine": machine,
            "path": target,
            "size": len(data),
            "sha256": hashlib.sha256(data).hexdigest(),
        }
        # one short append per line: whole lines, whatever else writes the file
        with path.open("a", encoding="utf-8") as out:
            out.write(json.dumps(line) + "\n")

    return note


async def _start_serial_haas(
    fleet: Fleet, folder: Path, k: int, baud: int, block_rate: float, dnc_timeout: float
) -> None:
    # Imported here: the serial front-end and the cable need ptys (POSIX).
    from opendnc.sim.cable.link import VirtualCable
    from opendnc.sim.haas.serial_front import SerialOptions, parse_mode, start_serial

    folder.mkdir(parents=True, exist_ok=True)
    cable = VirtualCable(baud).start()
    fleet._cables.append(cable)
    # a Haas on a cable is a classic control; Setting 143 ON: it answers MDC on the port too
    config = HaasConfig(model="VF-2", serial_number=f"{2000000 + k}", control=ControlType.CLASSIC)
    sim = SimHaas(config, folder, SimOptions(mdc_port=None, block_rate=block_rate))
    await sim.start()
    fleet._haas.append(sim)
    options = SerialOptions(baud=baud, mode=parse_mode("auto"), dnc_timeout=dnc_timeout)
    front = await start_serial(sim, cable.path_a, baud, None, options)
    sim.add_front_end(front)
    name = f"haas-serial-{k + 1}"
    fleet.sims[name] = sim
    fleet.serial_ports[name] = front
    fleet.machines.append(FleetMachine(name, "haas_serial", "", 0, folder, cable.path_b, baud))


def _start_fanuc(fleet: Fleet, folder: Path, n: int, baud: int) -> None:
    # Imported here: the cable needs ptys (POSIX), the simulator pyserial.
    from opendnc.sim.cable.link import VirtualCable
    from opendnc.sim.fanuc import VirtualFanuc
    from opendnc.tape.profiles import get_profile

    profile = get_profile("fanuc-0i").with_changes(baud=baud)
    cable = VirtualCable(baud, profile.bits_per_char).start()
    fleet._cables.append(cable)
    sim = VirtualFanuc(cable.path_a, folder, profile=profile).start()
    name = f"fanuc-{n + 1}"
    fleet.fanucs[name] = sim
    fleet.machines.append(FleetMachine(name, "serial", "", 0, folder, cable.path_b, baud))


async def _start_mtconnect(
    fleet: Fleet, root: Path, count: int, host: str, port: int, cycle: float, ftp: int = 0
) -> None:
    # Imported here: the agent is served by uvicorn (the server extra).
    from opendnc.sim.mtconnect.agent import VirtualAgent
    from opendnc.sim.mtconnect.machine import ScriptedMachine, run_cycles

    # an --ftp machine reports its state through the agent as well (an Okuma or a Mazak with
    # an agent and an FTP folder): its devices follow the --mtconnect ones
    names = [f"mtc-{i + 1}" for i in range(count)] + [f"ftp-{i + 1}" for i in range(ftp)]
    agent = VirtualAgent(names, host=host, port=port, buffer_size=max(1024, 64 * count))
    await agent.start()
    fleet.agent = agent
    for i, name in enumerate(names):
        machine = ScriptedMachine(agent, name)
        fleet.scripted[name] = machine
        # cycles of slightly different lengths, so the floor is not in lockstep
        length = cycle * (1 + 0.07 * (i % 5))
        fleet._cycles.append(asyncio.create_task(run_cycles(machine, length), name=name))
        fleet.machines.append(
            FleetMachine(name, "mtconnect", host, agent.port, root / name, device=name)
        )


async def _start_opcua(
    fleet: Fleet, root: Path, count: int, host: str, port: int, cycle: float, servers: int = 1
) -> None:
    # Imported here: asyncua is the server extra's.
    from opendnc.sim.opcua.machine import ScriptedMachineTool, run_cycles
    from opendnc.sim.opcua.server import VirtualOpcuaServer

    names = [f"opc-{i + 1}" for i in range(count)]
    where: dict[str, VirtualOpcuaServer] = {}
    for k in range(servers):
        mine = names[k::servers]  # round robin: every server some machines
        server = VirtualOpcuaServer(mine, host=host, port=port + k if port else 0)
        await server.start()
        fleet.opcua_servers.append(server)
        where.update(dict.fromkeys(mine, server))
    fleet.opcua = fleet.opcua_servers[0]
    for i, name in enumerate(names):
        server = where[name]
        machine = ScriptedMachineTool(server.machines[name])
        fleet.machine_tools[name] = machine
        length = cycle * (1 + 0.07 * (i % 5))
        fleet._cycles.append(asyncio.create_task(run_cycles(machine, length), name=name))
        fleet.machines.append(
            FleetMachine(name, "opcua", host, server.port, root / name, device=name)
        )


def _list_opcua(fleet: Fleet, root: Path, count: int, host: str, port: int, cycle: float) -> None:
    """List the ``opcua`` machines on the port their server will have; nothing of asyncua is
    imported yet (that alone is half a second of CPU)."""
    names = [f"opc-{i + 1}" for i in range(count)]
    if not port:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
            probe.bind((host, 0))
            port = int(probe.getsockname()[1])
    fleet.machines += [
        FleetMachine(name, "opcua", host, port, root / name, device=name) for name in names
    ]
    fleet._opcua_later = (names, host, port, cycle)


async def _serve_opcua(fleet: Fleet, names: list[str], host: str, port: int, cycle: float) -> None:
    """Build and start the OPC UA server of ``names`` (seconds of CPU), then run its machine
    tools' cycles."""
    # imported in a thread: the caller's loop keeps serving meanwhile
    module = await asyncio.to_thread(importlib.import_module, "opendnc.sim.opcua.server")
    from opendnc.sim.opcua.machine import ScriptedMachineTool, run_cycles

    server: VirtualOpcuaServer = module.VirtualOpcuaServer(names, host=host, port=port)
    await server.start()  # asyncua fills its standard address space in a thread
    fleet.opcua = server  # only now: Fleet.close stops a server that listens
    fleet.opcua_servers.append(server)
    for i, name in enumerate(names):
        machine = ScriptedMachineTool(server.machines[name])
        fleet.machine_tools[name] = machine
        length = cycle * (1 + 0.07 * (i % 5))
        fleet._cycles.append(asyncio.create_task(run_cycles(machine, length), name=name))


async def _start_ftp(fleet: Fleet, root: Path, n: int, host: str, port: int) -> None:
    # Imported here: pyftpdlib is the server extra's.
    from opendnc.sim.ftp import VirtualFtpFolder

    name = f"ftp-{n + 1}"
    folder = root / name
    served = VirtualFtpFolder(folder, host=host, port=port)
    await asyncio.to_thread(served.start)
    fleet.ftp[name] = served
    # its status device was started with the agent's
    for i, m in enumerate(fleet.machines):
        if m.name == name:
            fleet.machines[i] = FleetMachine(
                name, m.kind, m.host, m.port, folder, device=m.device, ftp_port=served.port
            )


def server_config(
    fleet: Fleet,
    *,
    bind: str = "127.0.0.1:8000",
    database: str = "",
    poll_interval: float = 1.0,
    library: Path | None = None,
    dripfeed: bool = False,
    mdc: bool = False,
    check: str | None = None,
    timezone: str | None = None,
    netshare: Path | None = None,
    netshare_interval: float = 5.0,
) -> str:
    """The ``opendnc serve`` configuration (TOML) for exactly the controls of ``fleet``
    (``dripfeed`` allows drip-feeding the serial Haas machines and the virtual Fanucs; ``mdc``
    has the server read their status by MDC on the cable, as they answer Q-commands there;
    ``check`` is the library's ``block`` or ``warn`` for program check errors, with ``library``;
    ``timezone`` the shop's clock; ``netshare`` a NAS folder whose programs the hybrid net
    share copies to every Haas NGC's share, scanned every ``netshare_interval`` seconds)."""

    def q(value: object) -> str:
        return json.dumps(str(value))  # a JSON string is a valid TOML basic string

    lines = ["[server]", f"bind = {q(bind)}"]
    if database:
        lines.append(f"database = {q(database)}")
    if timezone:
        lines.append(f"timezone = {q(timezone)}")
    if library is not None:
        lines += [
            "",
            "[library]",
            f"path = {q(library / 'programs')}",
            f"inbox = {q(library / 'inbox')}",
            f"archive = {q(library / 'archive')}",
        ]
        if check is not None:
            lines.append(f"check = {q(check)}")
    for m in fleet.machines:
        lines += [
            "",
            "[[machines]]",
            f"name = {q(m.name)}",
            f"kind = {q(m.kind)}",
            f"poll_interval = {poll_interval}",
        ]
        if m.kind not in ("mtconnect", "serial", "opcua"):
            lines.append(f"host = {q(m.host)}")
        if m.kind == "mtconnect":
            where = f"[{m.host}]" if ":" in m.host else m.host
            lines += [f"url = {q(f'http://{where}:{m.port}')}", f"device = {q(m.device)}"]
            if m.ftp_port:
                # programs through the control's FTP folder (docs/files.md)
                lines += [
                    "[machines.files]",
                    'mode = "ftp"',
                    f"host = {q(m.host)}",
                    f"port = {m.ftp_port}",
                    'user = "dnc"',
                    'password = "dnc"',
                    "receive = true",
                ]
        elif m.kind == "opcua":
            where = f"[{m.host}]" if ":" in m.host else m.host
            lines += [f"endpoint = {q(f'opc.tcp://{where}:{m.port}')}", f"machine = {q(m.device)}"]
        elif m.kind == "lsv2":
            lines.append(f"port = {m.port}")
        elif m.kind == "serial":
            # a virtual Fanuc: the tape engine's fanuc-0i profile at the cable's rate
            lines += [f"serial = {q(m.serial)}", 'profile = "fanuc-0i"', f"baud = {m.baud}"]
            if dripfeed:
                lines.append("dripfeed = true")
        elif m.kind == "haas_serial":
            lines += [f"serial = {q(m.serial)}", f"serial_profile = {{ baud = {m.baud} }}"]
            if mdc:
                lines.append("mdc = true")
            if dripfeed:
                lines.append("dripfeed = true")
        else:
            lines += [f"mdc_port = {m.port}", f"share = {q(m.root)}"]
            if m.dprnt_port:
                lines.append(f"dprnt = {q(f'tcp://{m.host}:{m.dprnt_port}')}")
    served = [m.name for m in fleet.machines if m.kind == "haas_ngc"]
    if netshare is not None and served:
        lines += [
            "",
            "[netshare]",
            f"path = {q(netshare)}",
            f"machines = [{', '.join(q(name) for name in served)}]",
            f"interval = {netshare_interval}",
        ]
    return "\n".join(lines) + "\n"
