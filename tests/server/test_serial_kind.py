"""The ``serial`` kind (tape-code controls) against virtual Fanucs on virtual RS-232 cables,
with the whole server in this process (docs/server.md#tape-code-controls-serial): a load lands
in the control's memory under its O-number, a punch lands in the inbox under its name, a
drip-feed opted in runs to its end with the card showing running, one not opted in is refused
with the reason.

One fleet (two virtual Fanucs) and one server serve every test of the module; each test selects
the control's mode it needs, as the operator would.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import pytest

from tests.peers import require_module

httpx = require_module("httpx")
require_module("serial")

from opendnc.server.access import auth  # noqa: E402
from opendnc.server.app import Server, build  # noqa: E402
from opendnc.server.config.shop import parse_config  # noqa: E402
from opendnc.server.core.status import MachineStatus  # noqa: E402
from opendnc.server.kinds.connector import Reception  # noqa: E402
from opendnc.server.kinds.serial import SerialMachine  # noqa: E402
from opendnc.server.store.models import Role  # noqa: E402
from opendnc.server.web import session as web_session  # noqa: E402
from opendnc.sim.fanuc.control import Mode, Selection, VirtualFanuc  # noqa: E402
from opendnc.sim.fleet import Fleet, server_config, start_fleet  # noqa: E402
from tests.server.harness import wait_for  # noqa: E402
from tests.server.inprocess_app import config_text  # noqa: E402
from tests.server.serving import serving  # noqa: E402

POLL_S = 0.2  # the machines' poll_interval: the listening window between two jobs


@dataclass
class Shop:
    server: Server
    client: Any
    key: str
    cookie: str  # a web session's, for the dashboard's pages
    fleet: Fleet

    def headers(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.key}"}

    def card(self, name: str) -> str:
        """The machine's card on the dashboard, as a browser gets it."""
        page = self.client.get("/", headers={"Cookie": f"{web_session.COOKIE}={self.cookie}"})
        page.raise_for_status()
        text = str(page.text)
        at = text.index(f'data-machine="{name}"')
        card = text[text.rindex("<div", 0, at) :]  # from its opening tag, which holds the state
        return card[: card.index("</dl>")]

    def fanuc(self, name: str) -> VirtualFanuc:
        return self.fleet.fanucs[name]

    def machine(self, name: str) -> dict[str, Any]:
        answer = self.client.get("/api/machines", headers=self.headers())
        answer.raise_for_status()
        return next(m for m in answer.json() if m["name"] == name)

    def put(self, name: str, text: str, *, release: bool = False) -> None:
        answer = self.client.put(f"/api/programs/{name}", content=text, headers=self.headers())
        assert answer.status_code in (200, 201), answer.text
        if release:
            number = answer.json()["number"]
            done = self.client.post(
                f"/api/programs/{name}/versions/{number}/release", headers=self.headers()
            )
            assert done.status_code == 200, done.text

    def queue(self, kind: str, program: str, machine: str, **more: Any) -> Any:
        return self.client.post(
            "/api/jobs",
            json={"kind": kind, "program": program, "machines": [machine], **more},
            headers=self.headers(),
        )

    def finished(self, job_id: int) -> dict[str, Any]:
        def done() -> dict[str, Any] | None:
            job: dict[str, Any] = self.client.get(
                f"/api/jobs/{job_id}", headers=self.headers()
            ).json()
            return job if job["state"] not in ("queued", "running") else None

        result: dict[str, Any] = wait_for(f"job {job_id}", done, timeout=30)
        return result


@pytest.fixture(scope="module")
def shop(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Shop]:
    root = tmp_path_factory.mktemp("serial-kind")
    fleet = asyncio.run(start_fleet(root / "machines", tnc=0, haas=0, fanuc=2))
    try:
        one, two = (m for m in fleet.machines if m.kind == "serial")
        machines: list[dict[str, object]] = [
            {
                "name": one.name,
                "kind": "serial",
                "serial": one.serial,
                "profile": "fanuc-0i",
                "baud": one.baud,
                "dripfeed": True,
                "poll_interval": POLL_S,
            },
            # not opted in to drip-feed: loads (checked by the punch back) and punches only
            {
                "name": two.name,
                "kind": "serial",
                "serial": two.serial,
                "baud": two.baud,
                "verify": "punch",
                "verify_timeout": 10.0,
                "poll_interval": POLL_S,
            },
        ]
        # the operator of fanuc-2 punches every program read straight back
        fanuc = fleet.fanucs[two.name]
        fanuc.options = replace(fanuc.options, punch_back=True)
        # a short request delay: the requested program (or the report) follows the punch soon
        text = config_text(root, machines, check="warn") + "\n[requests]\ndelay = 0.3\n"
        config = parse_config(text, base=root)
        server = build(config, database=f"sqlite:///{root / 'db.sqlite'}")
        with server.sessions.begin() as session:
            auth.create_user(session, "admin", Role.ADMIN)
            key = auth.create_key(session, "admin", Role.ADMIN, label="test")[1]
            cookie = auth.create_key(
                session, "admin", Role.ADMIN, label=auth.SESSION_LABEL, action="login"
            )[1]
        with serving(server) as url, httpx.Client(base_url=url, timeout=30) as client:
            shop = Shop(server, client, key, cookie, fleet)
            wait_for("both ports open", lambda: all(m["online"] for m in _machines(shop)))
            yield shop
    finally:
        asyncio.run(fleet.close())


def _machines(shop: Shop) -> list[dict[str, Any]]:
    answer = shop.client.get("/api/machines", headers=shop.headers())
    answer.raise_for_status()
    machines: list[dict[str, Any]] = answer.json()
    return machines


def _blocks(text: str) -> list[str]:
    """A program's blocks, without the tape's % lines and blank lines."""
    return [line.strip() for line in text.splitlines() if line.strip() not in ("", "%")]


LOAD = "%\nO0042 (BRACKET)\nG00 G90 G54 X0. Y0.\nG01 X12.5 F300.\nM30\n%\n"


def test_a_load_arrives_under_its_o_number_and_is_verified_by_the_punch_back(
    shop: Shop,
) -> None:
    fanuc = shop.fanuc("fanuc-2")
    fanuc.select(Selection(Mode.READ))  # EDIT + READ at the control
    shop.put("O0042.nc", LOAD, release=True)
    answer = shop.queue("send", "O0042.nc", "fanuc-2")
    assert answer.status_code == 201, answer.text
    job = shop.finished(answer.json()[0]["id"])
    assert job["state"] == "done", job
    # the outcome is in the audit row of the load: compared with what the control punched back
    audit = shop.client.get(
        "/api/audit", params={"action": "job.send"}, headers=shop.headers()
    ).json()
    (row,) = [r for r in audit if r["job_id"] == job["id"]]
    assert row["detail"]["verified"] is True
    assert row["detail"]["verification"] == "verified"
    stored = wait_for("the program in memory", lambda: "O0042.nc" in fanuc.programs())
    assert stored
    got = (fanuc.root / "O0042.nc").read_text()
    assert _blocks(got) == _blocks(LOAD)
    assert fanuc.alarms == []
    assert shop.machine("fanuc-2")["state"] == "ready"  # a load runs nothing


def test_a_program_without_the_controls_name_fails_before_a_byte_goes(shop: Shop) -> None:
    fanuc = shop.fanuc("fanuc-2")
    fanuc.select(Selection(Mode.READ))
    stored = fanuc.programs()
    shop.put("FACE.nc", "%\n(NO O-NUMBER)\nG00 X0.\nM30\n%\n", release=True)
    answer = shop.queue("send", "FACE.nc", "fanuc-2")
    assert answer.status_code == 201, answer.text
    job = shop.finished(answer.json()[0]["id"])
    assert job["state"] == "failed", job
    assert "no O-number line (O and up to 4 digits)" in job["error"]
    assert fanuc.programs() == stored  # the control got nothing to store
    assert fanuc.alarms == []


PUNCHED = "%\nO0123 (PUNCHED AT THE CONTROL)\nG00 X1. Y2.\nM30\n%\n"


def test_a_punch_from_the_control_lands_in_the_inbox_under_its_name(shop: Shop) -> None:
    fanuc = shop.fanuc("fanuc-1")
    fanuc.select(Selection(Mode.IDLE))
    (fanuc.root / "O0123.nc").write_text(PUNCHED)

    def punches() -> int:
        return sum(m.startswith("PUNCH") for m in fanuc.messages)

    for count in (1, 2):  # twice: the second never overwrites the first
        fanuc.select(Selection(Mode.PUNCH, "O0123"))  # the operator's PUNCH key
        wait_for("the punch to go out", lambda: punches() == count)  # noqa: B023

    def arrived() -> list[dict[str, Any]]:
        items: list[dict[str, Any]] = shop.client.get("/api/inbox", headers=shop.headers()).json()
        mine = [i for i in items if i["machine"] == "fanuc-1"]
        return mine if len(mine) == 2 else []

    items = wait_for(
        "both punches in the inbox",
        arrived,
        timeout=20,
        describe=lambda: (
            shop.client.get("/api/inbox", headers=shop.headers()).text,
            fanuc.messages,
            shop.machine("fanuc-1"),
        ),
    )
    assert sorted((i["name"], i["state"]) for i in items) == [
        ("O0123.nc", "new"),
        ("O0123.nc", "new"),
    ]
    for item in items:
        content = shop.client.get(f"/api/inbox/{item['id']}/content", headers=shop.headers())
        assert _blocks(content.text) == _blocks(PUNCHED)
    inbox = Path(shop.server.config.library.inbox)
    assert sorted(p.name for p in inbox.glob("O0123*")) == ["O0123.2.nc", "O0123.nc"]


MOVES = "".join(f"G01 X{i % 40}.5 Y{i % 9}. F600.\n" for i in range(400))
LONG = f"%\nO0300 (DRIP)\nG00 G90 G54 X0. Y0.\n{MOVES}M30\n%\n"


def test_a_dripfeed_opted_in_runs_to_the_end_and_the_card_shows_running(shop: Shop) -> None:
    fanuc = shop.fanuc("fanuc-1")
    fanuc.select(Selection(Mode.TAPE))  # TAPE/DNC mode at the control
    before = len(fanuc.executed)
    shop.put("O0300.nc", LONG, release=True)
    answer = shop.queue("dripfeed", "O0300.nc", "fanuc-1")
    assert answer.status_code == 201, answer.text
    job_id = answer.json()[0]["id"]

    def shown() -> tuple[dict[str, Any], str] | None:
        # the API's machine and the dashboard's card at the same moment of the feed
        machine, card = shop.machine("fanuc-1"), shop.card("fanuc-1")
        if machine["state"] == "running" and 'data-state="running"' in card:
            return machine, card
        return None

    running, card = wait_for("the card to show running", shown, timeout=20)
    assert running["status"]["program"] == "O0300.nc"
    assert running["status"]["execution"] == "ACTIVE"
    assert "Tape code · RS-232" in card
    job = shop.finished(job_id)
    assert job["state"] == "done", job
    assert job["bytes_done"] == len(LONG)
    # the control ran every block of the program, in order, to its M30
    wait_for(
        "the end of the tape",
        lambda: any(m.startswith("TAPE DONE") for m in fanuc.messages),
        timeout=10,
        describe=lambda: (fanuc.executed[-3:], fanuc.messages, job),
    )
    ran = [block for block in fanuc.executed[before:] if block != "%"]
    assert ran == _blocks(LONG)
    assert fanuc.alarms == []
    wait_for("the card to show ready again", lambda: shop.machine("fanuc-1")["state"] == "ready")


def test_a_dripfeed_not_opted_in_is_refused_with_the_reason(shop: Shop) -> None:
    fanuc = shop.fanuc("fanuc-2")
    shop.put("O0301.nc", "%\nO0301 (NO RUN)\nG00 X0.\nM30\n%\n", release=True)
    before = list(fanuc.executed)
    answer = shop.queue("dripfeed", "O0301.nc", "fanuc-2")
    assert answer.status_code == 409, answer.text
    assert "does not allow drip-feed" in answer.text
    assert "dripfeed = true" in answer.text
    assert fanuc.executed == before


def test_the_fleet_configuration_serves_its_fanucs(shop: Shop, tmp_path: Path) -> None:
    text = server_config(shop.fleet, dripfeed=True)
    config = parse_config(text, base=tmp_path)
    fanucs = {m.name: m for m in config.machines}
    assert set(fanucs) == {"fanuc-1", "fanuc-2"}
    for fleet_machine in shop.fleet.machines:
        machine = fanucs[fleet_machine.name]
        assert isinstance(machine, SerialMachine)
        assert machine.serial == fleet_machine.serial
        assert machine.tape.baud == fleet_machine.baud
        assert machine.dripfeed is True
        # opendnc check reads the machine's G-code as the profile's control speaks it
        assert machine.envelope is not None
        assert machine.envelope.control == "fanuc-mill"


def test_a_dripfeed_restarts_from_a_line_with_the_modal_state_first(shop: Shop) -> None:
    fanuc = shop.fanuc("fanuc-1")
    fanuc.select(Selection(Mode.TAPE))
    before, tapes = len(fanuc.executed), len(fanuc.messages)
    shop.put("O0300.nc", LONG, release=True)  # the same text: the released version stays
    answer = shop.queue("dripfeed", "O0300.nc", "fanuc-1", from_line=200)
    assert answer.status_code == 201, answer.text
    job = shop.finished(answer.json()[0]["id"])
    assert job["state"] == "done", job
    assert job["params"] == {"from_line": 200}
    # its bytes are the program's from line 200 on (the line is noted now and then: not checked)
    assert job["bytes_done"] == len("".join(LONG.splitlines(keepends=True)[199:]))
    wait_for(
        "the end of the tape",
        lambda: any(m.startswith("TAPE DONE") for m in fanuc.messages[tapes:]),
        timeout=10,
    )
    ran = [block for block in fanuc.executed[before:] if block != "%"]
    rest = _blocks("\n".join(LONG.splitlines()[199:]))
    assert ran[-len(rest) :] == rest  # line 200 on, each block once
    preamble = ran[: -len(rest)]
    assert preamble, ran[:5]
    # the work offset and absolute mode of line 3 are restored before line 200 runs
    assert any("G54" in block for block in preamble), preamble
    assert "G01 F600." in preamble  # the modal feed of the moves before line 200
    # and no block of lines 3 to 199 runs again
    assert not set(preamble) & set(_blocks(LONG)[1:198]), preamble


def _iso(text: str) -> bytes:
    """ISO characters with even parity in bit 8, as a Fanuc punches them (docs/tape.md)."""
    return bytes(c | 0x80 if bin(c).count("1") % 2 else c for c in text.encode("ascii"))


def _punched(*records: bytes, listens: int) -> tuple[list[Reception | None], list[MachineStatus]]:
    """The connector alone on a cable whose far end we write to as the control: ``records``
    written at once (as a control punches them), then ``listens`` listening windows; what each
    window received and every status the connector told."""
    from opendnc.server.kinds.registry import parse_machine
    from opendnc.server.kinds.serial.connector import TapeConnector
    from opendnc.sim.cable.link import VirtualCable
    from opendnc.transport import open_stream

    with VirtualCable(115200, 11) as cable:
        config = parse_machine(
            {"name": "lathe", "kind": "serial", "serial": cable.path_b, "baud": 115200}, "m"
        )
        assert isinstance(config, SerialMachine)
        told: list[MachineStatus] = []
        connector = TapeConnector(config, on_status=told.append)
        control = open_stream(cable.path_a, 115200, timeout=0.05)
        try:

            def punch() -> None:
                control.write(b"".join(records))
                control.drain()
                assert cable.wait_idle(5.0)  # all on the PC's side before its first read

            async def listen() -> list[Reception | None]:
                await connector.connect()
                try:
                    await asyncio.to_thread(punch)
                    return [await connector.listen(3.0) for _ in range(listens)]
                finally:
                    await connector.close()

            return asyncio.run(listen()), told
        finally:
            control.close()


def _record(text: str) -> bytes:
    """A punch as a Fanuc sends it: DC2, feed, the record, feed, DC4."""
    return b"\x12" + b"\0" * 4 + _iso(text) + b"\0" * 4 + b"\x14"


def test_a_damaged_punch_is_a_failed_reception_that_names_where() -> None:
    # a character with its parity bit wrong (the line's bit error) in the third block
    good = _iso("%\nO0007 (BAD LINE)\n")
    bad = bytes([_iso("G")[0] ^ 0x80]) + _iso("00 X1.\nM30\n%\n")
    (reception,), told = _punched(b"\x12" + b"\0" * 4 + good + bad, listens=1)
    assert reception is not None
    assert reception.data == b""  # nothing that could pass for the program
    assert reception.failed.startswith("parity error (TH) at line 3, column 1"), reception
    # the status said so while it lasted, and is ready again after
    assert [s.message for s in told] == ["receiving a punch", ""]
    assert told[-1].execution == "READY"


def test_two_punches_back_to_back_both_arrive() -> None:
    # both on the line before the port is read: the second starts in the first one's last read
    first, second = "%\nO0008 (ONE)\nG00 X1.\nM30\n%\n", "%\nO0009 (TWO)\nG00 X2.\nM30\n%\n"
    receptions, _ = _punched(_record(first), _record(second), listens=2)
    got = [(r.name, r.failed, _blocks(r.data.decode())) for r in receptions if r is not None]
    assert got == [("O0008.nc", "", _blocks(first)), ("O0009.nc", "", _blocks(second))]


def test_opendnc_check_reads_a_serial_machine_in_its_profiles_dialect(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from opendnc.cli.main import app

    config = tmp_path / "shop.toml"
    machine = '[[machines]]\nname = "{}"\nkind = "serial"\nserial = "/dev/null"\n{}\n'
    config.write_text(
        machine.format("fanuc", "")  # fanuc-0i: fanuc-mill
        + machine.format("okuma", 'profile = "okuma-osp"')  # no dialect of its own: guessed
        + machine.format("haas-on-tape", 'control = "haas-mill"')  # the key wins
    )
    # G187 (smoothness) is a Haas code that a Fanuc mill does not know
    program = tmp_path / "O0101.nc"
    program.write_text("%\nO0101 (SMOOTH)\nG21\nG187 P1 E0.01\nG00 G90 G54 X0. Y0.\nM30\n%\n")
    runner = CliRunner()

    def check(name: str) -> tuple[int, str]:
        args = ["check", str(program), "--machine", name, "--config", str(config)]
        done = runner.invoke(app, args)
        return done.exit_code, done.output

    code, out = check("fanuc")
    assert code == 1
    assert "G187 is not a G code of the Fanuc mill control" in out
    assert check("okuma")[0] == 0
    code, out = check("haas-on-tape")
    assert code == 0
    assert "haas-mill" in out
    # a Klartext program is no program for a Fanuc: refused on line 1, naming its control
    klartext = tmp_path / "POCKET.H"
    klartext.write_text("0 BEGIN PGM POCKET MM\n1 L Z+50 R0 FMAX M3\n2 END PGM POCKET MM\n")
    program = klartext
    code, out = check("fanuc")
    assert code == 1
    assert "POCKET.H:1: error: a heidenhain program cannot run on fanuc (fanuc-mill control)" in out


def test_a_request_punched_at_the_control_is_answered_in_its_own_digits(shop: Shop) -> None:
    # The operator punches a request for a program the library lacks: the report program
    # comes back into the control's memory as O9998 (a 0i takes 4 digits), saying why.
    fanuc = shop.fanuc("fanuc-2")
    fanuc.select(Selection(Mode.IDLE))
    (fanuc.root / "O9999.nc").write_text("%\nO9999 (REQ O0777)\n%\n")
    punched = sum(m.startswith("PUNCH") for m in fanuc.messages)
    fanuc.select(Selection(Mode.PUNCH, "O9999"))
    wait_for(
        "the punch to go out",
        lambda: sum(m.startswith("PUNCH") for m in fanuc.messages) > punched,
    )
    fanuc.select(Selection(Mode.READ))  # and selects READ for the answer
    wait_for("the report in memory", lambda: "O9998.nc" in fanuc.programs(), timeout=30)
    report = (fanuc.root / "O9998.nc").read_text()
    assert "O9998 (OPENDNC REQUEST FAILED)" in report
    assert "NOT IN LIBRARY" in report
    assert fanuc.alarms == []
