"""`opendnc demo`: the DNC server with a virtual shop floor, on embedded defaults.

Starts two virtual TNCs, a virtual Haas NGC (MDC, net share and a DPRNT port), a virtual
Haas and a virtual Fanuc (tape code, the ``serial`` kind) on virtual RS-232 cables, a machine
behind a virtual MTConnect agent, a machine tool of a virtual umati OPC UA server and a control
that takes programs through its FTP folder (status through the agent) in this process, fills
a library with example programs (released ones and a draft with two versions), and runs the
server on SQLite in a scratch folder, on this computer's time zone (or ``--timezone``), with a
hybrid net share: a NAS folder holding programs as a CAM office leaves them (one the released
version, one a draft, one edited after its release, one the library never saw), copied to the
NGC's share. It prints the dashboard's address and a login first, then an API key, and serves
until Ctrl-C.
``--check`` sends a released program of its family to every machine that takes programs, prints
what happened and exits (what the test suite runs).

The OPC UA server's address space takes seconds of CPU to build: the demo builds it in the
background (its machine comes online when it listens), and ``--check`` leaves that machine
out, so the check costs about what it did before it was added.
"""

from __future__ import annotations

import asyncio
import contextlib
import secrets
import signal
import socket
import tempfile
from collections.abc import Callable, Sized
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import typer

from opendnc.cli.common import cli_errors, console
from opendnc.cli.serve import bind_option, listen_socket, require_server_extra
from opendnc.errors import DncError, InputError

if TYPE_CHECKING:
    from opendnc.server.app import Server
    from opendnc.sim.fleet import Fleet, FleetMachine

T = TypeVar("T")

# What the virtual NGC runs once at start so its DPRNT lines reach the machine's page.
PRINTS = (
    "%\nO03000 (PROBE BORE, PRINT SIZE)\n#100 = 1\n#101 = 1.0002\n"
    "WHILE [#100 LE 3] DO1\nDPRNT[BORE*#100[20]*DIA*#101[24]]\n"
    "#100 = #100 + 1\n#101 = #101 - 0.0001\nEND1\nM30\n%\n"
)


# Example programs: Haas ISO programs and a Heidenhain conversational one (CRLF, as stored).
EXAMPLES: dict[str, list[bytes]] = {
    "O01000.nc": [
        b"%\r\nO01000 (FACE MILL 3IN)\r\nG20\r\nT1 M06\r\nG00 G90 G54 X-1.6 Y0.\r\n"
        b"S3000 M03\r\nG43 H01 Z0.1 M08\r\nG01 Z0. F20.\r\nX7.6 F40.\r\nG00 Z1. M09\r\n"
        b"G28 G91 Z0.\r\nM30\r\n%\r\n"
    ],
    "O02000.nc": [
        b"%\r\nO02000 (DRILL 4X)\r\nG20\r\nT2 M06\r\nG00 G90 G54 X0.5 Y0.5\r\nS2500 M03\r\n"
        b"G43 H02 Z0.1 M08\r\nG81 Z-0.5 R0.1 F10.\r\nX1.5\r\nY1.5\r\nX0.5\r\nG80 M09\r\n"
        b"G28 G91 Z0.\r\nM30\r\n%\r\n",
        b"%\r\nO02000 (DRILL 4X, PECK)\r\nG20\r\nT2 M06\r\nG00 G90 G54 X0.5 Y0.5\r\nS2500 M03\r\n"
        b"G43 H02 Z0.1 M08\r\nG83 Z-0.5 R0.1 Q0.1 F10.\r\nX1.5\r\nY1.5\r\nX0.5\r\nG80 M09\r\n"
        b"G28 G91 Z0.\r\nM30\r\n%\r\n",
    ],
    "O03000.nc": [PRINTS.replace("\n", "\r\n").encode()],  # the one the NGC runs
    "POCKET.H": [
        b"0 BEGIN PGM POCKET MM\r\n1 BLK FORM 0.1 Z X+0 Y+0 Z-20\r\n"
        b"2 BLK FORM 0.2 X+100 Y+100 Z+0\r\n3 TOOL CALL 1 Z S4000 F800\r\n"
        b"4 L Z+50 R0 FMAX M3\r\n5 L X+50 Y+50 R0 FMAX\r\n6 L Z-5 F200\r\n"
        b"7 L Z+50 R0 FMAX M30\r\n8 END PGM POCKET MM\r\n"
    ],
}
# O04000 is released; the NAS holds a copy edited after that (the net share page flags it).
EXAMPLES["O04000.nc"] = [
    b"%\r\nO04000 (SPOT DRILL)\r\nG20\r\nT3 M06\r\nG00 G90 G54 X1. Y1.\r\nS2000 M03\r\n"
    b"G43 H03 Z0.1 M08\r\nG81 Z-0.1 R0.1 F8.\r\nX2.\r\nG80 M09\r\nG28 G91 Z0.\r\nM30\r\n%\r\n"
]
# A Fanuc 0i program (tape code, LF, a 4-digit O-number) for the virtual Fanuc.
EXAMPLES["O0100.nc"] = [
    b"%\nO0100 (FACE MILL, FANUC)\nG21\nT1 M06\nG00 G90 G54 X-40. Y0.\nS3000 M03\n"
    b"G43 H01 Z2. M08\nG01 Z0. F500.\nX190. F1000.\nG00 Z25. M09\nG91 G28 Z0.\nM30\n%\n"
]
RELEASED = ("O01000.nc", "O04000.nc", "POCKET.H", "O0100.nc")
# The demo's NAS folder: file name -> bytes, as a CAM office drops them.
NAS_FILES: dict[str, bytes] = {
    "O01000.nc": EXAMPLES["O01000.nc"][0],  # the released version
    "O02000.nc": EXAMPLES["O02000.nc"][1],  # a draft nobody released yet
    "O04000.nc": EXAMPLES["O04000.nc"][0].replace(b"F8.", b"F12."),  # edited after release
    "O05000.nc": b"%\r\nO05000 (CHAMFER, NEW JOB)\r\nG20\r\nT4 M06\r\nG00 G90 G54 X0. Y0.\r\n"
    b"S4000 M03\r\nG43 H04 Z0.1\r\nG01 Z-0.05 F10.\r\nG28 G91 Z0.\r\nM30\r\n%\r\n",
}


# Two shifts every day of the week (a demo runs on a Sunday too): the utilization page per
# shift has something to show, and its figures are over shift time.
DEMO_SHIFTS = """
[[shifts]]
name = "early"
start = "06:00"
end = "14:00"
days = ["mon-sun"]

[[shifts]]
name = "late"
start = "14:00"
end = "22:00"
days = ["mon-sun"]
"""


def demo_goals(names: list[str]) -> str:
    """The demo's ``[goals]``: parts per shift for the first machines, one per day for the
    next, none for the rest (a card without a goal shows that too)."""
    lines = ["", "[goals]"]
    for i, name in enumerate(names):
        if i % 3 == 0:
            lines.append(f'"{name}" = {{ shift = {40 + 10 * i} }}')
        elif i % 3 == 1:
            lines.append(f'"{name}" = {{ day = {60 + 10 * i} }}')
    return "\n".join(lines) + "\n"


def demo(
    tour: bool = typer.Option(
        False, "--tour", help="The short command-line tour of one virtual TNC and Haas instead."
    ),
    bind: str = typer.Option("127.0.0.1:8000", "--bind", help="HOST:PORT of the server."),
    folder: Path | None = typer.Option(
        None, "--dir", help="Keep the database and files here (default: a scratch folder)."
    ),
    check: bool = typer.Option(
        False, "--check", help="Send a program to every machine, report, and exit."
    ),
    timezone: str | None = typer.Option(
        None,
        "--timezone",
        help="The shop's clock, an IANA name like Europe/Berlin (default: this computer's).",
    ),
) -> None:
    """Run the DNC server with a virtual shop floor (TNCs, Haas, a Fanuc, MTConnect, OPC UA and
    FTP machines) and print a login."""
    if tour:
        from opendnc.cli.demo import demo as cli_tour

        cli_tour()
        return
    with cli_errors():
        require_server_extra()
        from opendnc.server.core.host_zone import host_zone_name

        zone = timezone or host_zone_name()
        host, port = bind_option(bind)
        # bound before the virtual machines start: a port in use is one line, nothing started
        with listen_socket(host, port) as listener:
            if folder is not None:
                folder.mkdir(parents=True, exist_ok=True)
                asyncio.run(_run(folder, host, listener, check, zone))
            else:
                with tempfile.TemporaryDirectory(prefix="opendnc-demo-") as tmp:
                    asyncio.run(_run(Path(tmp), host, listener, check, zone))


async def _run(folder: Path, host: str, listener: socket.socket, check: bool, zone: str) -> None:
    import uvicorn

    from opendnc.server.app import build
    from opendnc.server.config.shop import parse_config
    from opendnc.sim.fleet import start_fleet

    port = listener.getsockname()[1]  # the real one when --bind said :0
    # the NGC prints DPRNT to a port of its own: the demo shows a DPRNT source
    fleet = await start_fleet(
        folder / "machines",
        tnc=2,
        haas=1,
        serial_haas=1,
        fanuc=1,
        dprnt=True,
        mtconnect=1,
        ftp=1,
        # status only, and its server costs seconds of CPU: not what --check is for
        opcua=0 if check else 1,
        opcua_later=True,  # built once the demo is announced and usable
    )
    try:
        nas = folder / "nas"
        text = _write_shop(folder, nas, fleet, f"{host}:{port}", zone)
        shop = parse_config(text, base=folder, source=folder / "shop.toml")
        server = build(shop, database=f"sqlite:///{folder / 'opendnc.db'}", sweep_interval=1.0)
        password = secrets.token_urlsafe(9)
        viewer_password = secrets.token_urlsafe(9)
        key = _seed(server, password, viewer_password)
        # An open dashboard holds an event stream that never ends by itself: at Ctrl-C it
        # gets two seconds, then goes (as `serve` does with its own deadline).
        settings = uvicorn.Config(
            server.app, log_level="warning", lifespan="on", timeout_graceful_shutdown=2
        )
        web = uvicorn.Server(settings)
        serving = asyncio.create_task(web.serve(sockets=[listener]))
        while not web.started:
            if serving.done():
                with contextlib.suppress(SystemExit):  # uvicorn's end of a failed start-up
                    serving.result()
                raise InputError(f"the server on {host}:{port} stopped at once (see above)")
            await asyncio.sleep(0.05)
        url = f"http://{host}:{port}/"
        _announce(url, (password, viewer_password, key), fleet, zone, nas)
        fleet.start_opcua()
        printing = asyncio.create_task(_print_dprnt(server, fleet))
        opcua = asyncio.create_task(_opcua_ready(fleet))
        try:
            if check:
                await _check(server, fleet)
            else:
                stop = asyncio.Event()
                loop = asyncio.get_running_loop()
                for sig in (signal.SIGINT, signal.SIGTERM):
                    loop.add_signal_handler(sig, stop.set)
                console.print("serving; Ctrl-C stops the demo", highlight=False)
                await stop.wait()
        finally:
            for task in (printing, opcua):
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
            web.should_exit = True
            await serving
            server.engine.dispose()
    finally:
        await fleet.close()
    console.print("demo finished")


def _write_shop(folder: Path, nas: Path, fleet: Fleet, bind: str, zone: str) -> str:
    """Fill the NAS folder and write the demo's ``shop.toml``; its text."""
    from opendnc.sim.fleet import server_config

    nas.mkdir(exist_ok=True)
    for name, data in NAS_FILES.items():
        if not (nas / name).exists():  # a kept --dir: a file changed there stays so
            (nas / name).write_bytes(data)
    text = server_config(
        fleet,
        bind=bind,
        poll_interval=0.5,
        library=folder / "library",
        dripfeed=True,  # a virtual machine: nothing moves
        timezone=zone,
        netshare=nas,
        netshare_interval=1.0,
    )
    text += DEMO_SHIFTS  # utilization per shift has something to show
    text += demo_goals([m.name for m in fleet.machines])  # and every card a goal
    (folder / "shop.toml").write_text(text)
    return text


def _seed(server: Server, password: str, viewer_password: str) -> str:
    """The demo's users (admin and viewer, with these passwords) and example programs; a new
    admin API key."""
    from opendnc.server.access import auth
    from opendnc.server.library import versions as library
    from opendnc.server.store.models import Role

    with server.sessions.begin() as session:
        for user, role, secret in (
            ("admin", Role.ADMIN, password),
            ("viewer", Role.VIEWER, viewer_password),
        ):
            if auth.find_user(session, user) is None:
                auth.create_user(session, user, role, password=secret, actor="demo")
            else:  # a kept --dir: the login printed below must be the one that works
                auth.set_password(session, user, secret, actor="demo")
        _, key = auth.create_key(session, "admin", Role.ADMIN, label="demo", actor="demo")
        for name, versions in EXAMPLES.items():
            for data in versions:
                library.add_version(session, name, data, author="demo", source="example")
            if name in RELEASED:
                library.release(session, name, 1, actor="demo")
    return key


def _announce(url: str, secrets_: tuple[str, str, str], fleet: Fleet, zone: str, nas: Path) -> None:
    """Print where the demo is and how to log in."""
    password, viewer_password, key = secrets_
    console.print(f"dashboard: {url}", highlight=False, soft_wrap=True)
    console.print(f"login: admin / {password}", highlight=False, soft_wrap=True)
    console.print(f"(also: viewer / {viewer_password}, read-only)", highlight=False, soft_wrap=True)
    console.print(f"API key: {key}", highlight=False, soft_wrap=True)
    console.print(
        f"try: curl -H 'Authorization: Bearer {key}' {url}api/machines",
        highlight=False,
        soft_wrap=True,
    )
    names = ", ".join(f"{m.name} ({m.kind})" for m in fleet.machines)
    console.print(f"machines: {names}", highlight=False, soft_wrap=True)
    console.print(f"times in {zone}; net share folder: {nas}", highlight=False, soft_wrap=True)
    if any(m.kind == "opcua" for m in fleet.machines):
        console.print(
            "the OPC UA machine comes online in a few seconds (its server is being built)",
            highlight=False,
        )
    else:
        console.print("(--check leaves out the OPC UA machine: status only)", highlight=False)


async def _opcua_ready(fleet: Fleet) -> None:
    """Say when the virtual OPC UA server built in the background listens, or why not."""
    started = fleet.opcua_started
    if started is None:
        return
    try:
        await asyncio.shield(started)  # Fleet.close cancels it, not this watcher
    except Exception as exc:  # whatever asyncua raised: the rest of the demo goes on
        console.print(f"the virtual OPC UA server did not start: {exc!r}", highlight=False)
        return
    if fleet.opcua is not None:
        console.print(f"virtual OPC UA server listening on {fleet.opcua.url}", highlight=False)


async def _print_dprnt(server: object, fleet: object) -> None:
    """Once the server reads the NGC's DPRNT port, run a program there that prints three
    lines (a cycle start at the control): the demo's DPRNT console is not empty."""
    from opendnc.sim.fleet import Fleet

    assert isinstance(fleet, Fleet)
    for machine in fleet.machines:
        sim = fleet.sims.get(machine.name)
        if not machine.dprnt_port or sim is None or sim.dprnt_tcp is None:
            continue
        if await sim.dprnt_tcp.wait_reader(60):
            number = sim.control.save_program(PRINTS)
            sim.control.start_program(number)


async def _check(server: object, fleet: object) -> None:
    """Send a released program to every machine that takes programs (O01000 to a Haas and to
    the FTP folder's control, POCKET.H to a TNC, O0100 to a tape-code control) and wait for
    the outcome; then for the NGC's DPRNT lines and the net share's copies."""
    from opendnc.server.app import Server
    from opendnc.sim.fleet import Fleet

    assert isinstance(server, Server)
    assert isinstance(fleet, Fleet)
    deadline = asyncio.get_running_loop().time() + 60
    await _all_online(server, deadline)
    await _send_everywhere(server, fleet, deadline)
    await _dprnt_printed(server, deadline)
    await _net_share_copied(server, fleet, deadline)


async def _poll(probe: Callable[[], T], done: Callable[[T], bool], deadline: float) -> T:
    """``probe()`` every 0.1 s until ``done`` holds of its answer or the loop's clock passes
    ``deadline``; its last answer."""
    loop = asyncio.get_running_loop()
    while True:
        value = probe()
        if done(value) or loop.time() > deadline:
            return value
        await asyncio.sleep(0.1)


async def _all_online(server: Server, deadline: float) -> None:
    """Wait until every machine is online."""
    machines = server.machines.machines.values()
    away = await _poll(lambda: [m.config.name for m in machines if not m.online], _empty, deadline)
    if away:
        raise DncError(f"machines not online: {', '.join(away)}")
    console.print("all machines online", highlight=False)


def _empty(items: Sized) -> bool:
    return not items


async def _send_everywhere(server: Server, fleet: Fleet, deadline: float) -> None:
    """Send each machine a released program of its own family and wait until all are sent."""
    from opendnc.server import actions
    from opendnc.server.access.auth import Principal
    from opendnc.server.actions.models import JobRequest
    from opendnc.server.jobs import queue as jobs
    from opendnc.server.store.models import Job, JobKind, JobState, Role

    # each machine a released program of its own family (the library's program check
    # refuses a Haas program on a TNC): through the actions layer, as a person's send would go
    svc = server.core.get(actions.Services)
    demo = Principal("demo", Role.ADMIN)
    created = []
    for program in dict.fromkeys(_program_for(m) for m in fleet.machines):
        names = [m.name for m in fleet.machines if _program_for(m) == program]
        if program is not None:
            order = JobRequest(kind=JobKind.SEND, program=program, machines=names)
            created += await asyncio.to_thread(actions.queue.create_jobs, svc, demo, order)
    ids = [j.id for j in created]
    programs = {j.id: j.program for j in created}

    def states() -> list[Job]:
        with server.sessions() as session:
            return [jobs.get_job(session, i) for i in ids]

    found = await _poll(states, lambda js: all(j.state.finished for j in js), deadline)
    if not all(j.state.finished for j in found):
        raise DncError("the demo's jobs did not finish in time")
    for job in found:
        outcome = "sent" if job.state is JobState.DONE else f"{job.state.value}: {job.error}"
        console.print(f"{programs[job.id]} -> {job.machine}: {outcome}", highlight=False)
    if any(j.state is not JobState.DONE for j in found):
        raise DncError("not every machine received the program")


def _program_for(machine: FleetMachine) -> str | None:
    """The demo's released program of ``machine``'s family; None for a status-only one."""
    if machine.ftp_port or machine.kind.startswith("haas"):
        return "O01000.nc"  # ISO G-code: a Haas, and the FTP folder's control (an Okuma's)
    return {"lsv2": "POCKET.H", "serial": "O0100.nc"}.get(machine.kind)


async def _dprnt_printed(server: Server, deadline: float) -> None:
    """Wait for the NGC's DPRNT lines, captured by the server (the program it runs at start
    prints 3)."""
    from sqlalchemy import select

    from opendnc.server.store.models import DprntLine

    def lines() -> list[str]:
        with server.sessions() as session:
            return list(session.scalars(select(DprntLine.text).order_by(DprntLine.id)))

    printed = await _poll(lines, lambda found: len(found) >= 3, deadline)
    for line in printed:
        console.print(f"DPRNT haas-1: {line}", highlight=False)
    if len(printed) < 3:
        raise DncError("the demo's DPRNT lines did not arrive")


async def _net_share_copied(server: Server, fleet: Fleet, deadline: float) -> None:
    """Wait until the net share copied the NAS folder's programs to every Haas NGC's share."""
    from sqlalchemy import select

    from opendnc.server.store.models import AuditEntry

    served = [m.name for m in fleet.machines if m.kind == "haas_ngc"]
    wanted = {(machine, name) for machine in served for name in NAS_FILES}

    def pushed() -> set[tuple[str, str]]:
        with server.sessions() as session:
            rows = session.execute(
                select(AuditEntry.machine, AuditEntry.program).where(
                    AuditEntry.action == "netshare.push", AuditEntry.result == "ok"
                )
            ).all()
        return {(m or "", p or "") for m, p in rows} & wanted

    copied = await _poll(pushed, lambda found: found == wanted, deadline)
    for machine in served:
        names = ", ".join(sorted(p for m, p in copied if m == machine))
        console.print(f"net share -> {machine}: {names}", highlight=False)
    if copied != wanted:
        raise DncError("the net share did not copy the NAS folder's programs in time")
