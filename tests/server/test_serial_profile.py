"""A serial Haas set to plain text (``protocol = "text"``): the server applies the port's
profile, checked byte for byte at the other end of a real virtual cable (``opendnc sim cable``).

The test is the control: it reads what the server sends (tape leader, the program with the
profile's end of block, trailer; nothing before its XON; a pause after every line) and punches
programs at the server as text (leader and punch codes around them; one that stops short).
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from opendnc.errors import TransportTimeout
from opendnc.server.config.shop import ConfigError, parse_config
from opendnc.transport import PortStream, open_stream
from tests.server.conftest import on
from tests.server.harness import (
    Procs,
    auth,
    create_key,
    free_port,
    httpx,
    start_server,
    wait_for,
    wait_jobs,
)

BAUD = 115200
MACHINE = "vf-text"
LINE_DELAY = 0.25
PROGRAM = b"%\nO01234 (PROFILE)\nG00 X1.\nM30\n%\n"


@dataclass
class Shop:
    client: httpx.Client
    key: str
    control: PortStream  # the control's end of the cable
    inbox: Path


@pytest.fixture
def shop(tmp_path: Path, procs: Procs, db_url: str) -> Iterator[Shop]:
    control_end, pc_end = tmp_path / "control", tmp_path / "pc"
    procs.start(
        "cable",
        "sim",
        "cable",
        "--baud",
        str(BAUD),
        "--link-a",
        str(control_end),
        "--link-b",
        str(pc_end),
    )
    wait_for("the cable", lambda: control_end.exists() and pc_end.exists())
    port = free_port()
    q = json.dumps
    profile = (
        f'{{ baud = {BAUD}, protocol = "text", eob = "CRLF", leader = 10, trailer = 6, '
        f"line_delay = {LINE_DELAY}, wait_for_xon = true, idle_timeout = 1.0 }}"
    )
    config = tmp_path / "shop.toml"
    config.write_text(
        "\n".join(
            [
                "[server]",
                f"bind = {q(f'127.0.0.1:{port}')}",
                "[library]",
                f"path = {q(str(tmp_path / 'programs'))}",
                f"inbox = {q(str(tmp_path / 'inbox'))}",
                f"archive = {q(str(tmp_path / 'archive'))}",
                "[[machines]]",
                f"name = {q(MACHINE)}",
                'kind = "haas_serial"',
                f"serial = {q(str(pc_end))}",
                "poll_interval = 0.5",
                f"serial_profile = {profile}",
            ]
        )
        + "\n"
    )
    key = create_key(config, db_url)
    control = open_stream(str(control_end), BAUD, timeout=0.02)
    try:
        with start_server(procs, config, db_url) as client:
            wait_for(
                "the machine online",
                lambda: client.get(f"/api/machines/{MACHINE}", headers=auth(key)).json()["online"],
            )
            yield Shop(client, key, control, tmp_path / "inbox")
    finally:
        control.close()


def _read_for(control: PortStream, seconds: float) -> list[tuple[float, bytes]]:
    """What arrives within ``seconds``, with the time each piece came."""
    got = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            data = control.read(4096)
        except TransportTimeout:
            continue
        if data:
            got.append((time.monotonic(), data))
    return got


def _job(shop: Shop, job_id: int) -> dict[str, Any]:
    job: dict[str, Any] = shop.client.get(f"/api/jobs/{job_id}", headers=auth(shop.key)).json()
    return job


@on("postgresql")
def test_a_text_load_has_leader_trailer_eob_waits_for_xon_and_paces_lines(shop: Shop) -> None:
    client, key = shop.client, shop.key
    put = client.put("/api/programs/O01234.nc", content=PROGRAM, headers=auth(key))
    assert put.status_code == 201, put.text
    queued = client.post(
        "/api/jobs",
        headers=auth(key),
        json={"kind": "send", "program": "O01234.nc", "version": 1, "machines": [MACHINE]},
    )
    assert queued.status_code == 201, queued.text
    job_id = queued.json()[0]["id"]
    wait_for("the load to start", lambda: _job(shop, job_id)["state"] == "running")
    # The control has not said XON yet: nothing may come.
    assert _read_for(shop.control, 0.5) == []
    xon_at = time.monotonic()  # before the write: the server cannot have seen XON earlier
    shop.control.write(b"\x11")
    pieces: list[tuple[float, bytes]] = []

    def whole() -> bool:
        pieces.extend(_read_for(shop.control, 0.1))
        return b"".join(p for _, p in pieces).endswith(b"%\r\n" + b"\0" * 6)

    wait_for("the whole program on the wire", whole, describe=lambda: pieces)
    wire = b"".join(p for _, p in pieces)
    assert wire == (b"\0" * 10 + b"%\r\nO01234 (PROFILE)\r\nG00 X1.\r\nM30\r\n%\r\n" + b"\0" * 6)
    (done,) = wait_jobs(client, key, [job_id])
    assert done["state"] == "done", done["error"]
    audit = client.get("/api/audit", headers=auth(key), params={"action": "job.send"}).json()
    (row,) = [r for r in audit if r["job_id"] == job_id]
    assert row["detail"]["verification"] == "not verified (plain text has no check)"

    # The pacing: the leader leaves after XON, and every line after it only once the line
    # delay after the one before is over, so the k-th piece after the leader (the five lines,
    # then the trailer) cannot reach the control before k delays after XON. Every clock
    # here is the one monotonic clock of the machine, and whatever a busy machine delays
    # (the server, the cable, this reader) only makes a piece arrive later: the bound holds
    # however loaded the machine is, where gaps between two observed arrivals would not (a
    # late observer shortens the next gap).
    starts = _line_starts(pieces)
    assert len(starts) == 7  # the leader, the five lines and the trailer
    late = [
        (k, round(at - xon_at, 3)) for k, at in enumerate(starts) if at - xon_at < k * LINE_DELAY
    ]
    assert late == [], late


def _line_starts(pieces: list[tuple[float, bytes]]) -> list[float]:
    """When the first byte of each piece of the tape arrived: the leader, each line (after a
    line end or after the leader's NULs) and the trailer."""
    starts = []
    seen = b""
    for at, data in pieces:
        for byte in data:
            if not seen or seen.endswith(b"\n") or (seen[-1] == 0 and byte != 0):
                starts.append(at)
            seen += bytes([byte])
    return starts


@on("sqlite")
def test_a_text_punch_lands_in_the_inbox_and_one_cut_short_is_kept_apart(shop: Shop) -> None:
    client, key = shop.client, shop.key
    shop.control.write(
        b"\0" * 20 + b"\x12%\r\nO05555 (TEXT PUNCH)\r\nG01 X2.5\r\nM30\r\n%\r\n\x14" + b"\0" * 20
    )
    items = wait_for(
        "the punch in the inbox",
        lambda: client.get("/api/inbox", headers=auth(key)).json(),
    )
    assert [(i["name"], i["state"]) for i in items] == [("O05555.nc", "new")]
    content = client.get(f"/api/inbox/{items[0]['id']}/content", headers=auth(key)).content
    assert content == b"%\nO05555 (TEXT PUNCH)\nG01 X2.5\nM30\n%\n"

    # The operator's punch stops before its closing %: after the idle timeout (1 s) the
    # reception is kept apart with the reason.
    shop.control.write(b"%\r\nO06666\r\nG01 X1.")

    def failed() -> list[dict[str, Any]]:
        found: list[dict[str, Any]] = client.get(
            "/api/inbox", headers=auth(key), params={"state": "failed"}
        ).json()
        return found

    (broken,) = wait_for("the failed reception", failed)
    assert broken["name"] == "O06666.nc"
    assert broken["reason"].startswith("no end trigger '%' within 1 s of the last character")
    assert (shop.inbox / "failed" / "O06666.nc").read_bytes() == b"%\nO06666\nG01 X1.\n"
    assert [i["name"] for i in client.get("/api/inbox", headers=auth(key)).json()] == ["O05555.nc"]


@pytest.mark.parametrize(
    ("profile", "key"),
    [
        ('protocol = "zmodem"', "protocol"),
        ('eob = "LFCR"', "eob"),
        ('leader_char = "ab"', "leader_char"),
        ('leader_char = "\\n"', "leader_char"),
        ('flow = "none", wait_for_xon = true', "wait_for_xon"),
        ('start_trigger = "%%%%%%%%%%%%%%%%%"', "start_trigger"),
        ("idle_timeout = 0", "idle_timeout"),
        ("line_delay = 11", "line_delay"),
    ],
)
def test_bad_profile_names_the_key(profile: str, key: str, tmp_path: Path) -> None:
    toml = '[[machines]]\nname = "m"\nkind = "haas_serial"\nserial = "/dev/x"\n'
    with pytest.raises(ConfigError) as caught:
        parse_config(f"{toml}serial_profile = {{ {profile} }}\n", base=tmp_path)
    assert caught.value.key == f"machines[0].serial_profile.{key}"


def test_profile_keys_that_mean_nothing_to_the_machine_are_refused(tmp_path: Path) -> None:
    lsv2 = '[[machines]]\nname = "m"\nkind = "lsv2"\nserial = "/dev/x"\n'
    with pytest.raises(ConfigError) as caught:
        parse_config(f"{lsv2}serial_profile = {{ leader = 10 }}\n", base=tmp_path)
    assert caught.value.key == "machines[0].serial_profile.leader"
    haas = '[[machines]]\nname = "m"\nkind = "haas_serial"\nserial = "/dev/x"\ndprnt = "serial"\n'
    with pytest.raises(ConfigError) as caught:
        parse_config(f'{haas}serial_profile = {{ protocol = "text" }}\n', base=tmp_path)
    assert caught.value.key == "machines[0].dprnt"
