"""``opendnc sim fleet --config-out``: the configuration names exactly the controls the fleet
started, and ``opendnc serve`` with it finds every one of them online."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from opendnc.server.config.shop import load_config
from tests.server.conftest import on
from tests.server.harness import (
    Procs,
    auth,
    create_key,
    free_port,
    listening,
    start_server,
    wait_for,
)


@on("sqlite")
def test_fleet_config_out_serves_exactly_the_started_controls(
    tmp_path: Path, procs: Procs, db_url: str
) -> None:
    config = tmp_path / "shop.toml"
    port = free_port()
    procs.start(
        "fleet",
        "sim",
        "fleet",
        "--tnc",
        "3",
        "--haas",
        "2",
        "--serial-haas",
        "1",
        "--mtconnect",
        "2",
        "--opcua",
        "2",
        "--fanuc",
        "1",
        "--root",
        str(tmp_path / "machines"),
        "--config-out",
        str(config),
        "--bind",
        f"127.0.0.1:{port}",
        "--poll",
        "0.3",
    )
    wait_for(
        "the fleet", lambda: "listening" in procs.log("fleet"), describe=lambda: procs.log("fleet")
    )
    shop = load_config(config)
    kinds = Counter(m.kind for m in shop.machines)
    assert kinds == {
        "lsv2": 3,
        "haas_ngc": 2,
        "haas_serial": 1,
        "mtconnect": 2,
        "opcua": 2,
        "serial": 1,
    }
    assert len({m.name for m in shop.machines}) == 11
    assert (shop.server.bind_host, shop.server.bind_port) == ("127.0.0.1", port)
    for m in shop.machines:
        assert m.poll_interval == 0.3
        if m.kind == "lsv2":
            assert listening(int(m.port))(), m
        elif m.kind == "haas_ngc":
            assert listening(m.mdc_port)(), m
            assert Path(m.share).is_dir(), m
        elif m.kind == "mtconnect":
            assert listening(int(m.url.rsplit(":", 1)[1]))(), m
            assert m.device.startswith("mtc-"), m
        elif m.kind == "opcua":
            assert listening(int(m.endpoint.rsplit(":", 1)[1]))(), m
            assert m.machine.startswith("opc-"), m
        else:
            assert Path(m.serial).exists(), m
    key = create_key(config, db_url)
    with start_server(procs, config, db_url) as client:

        def machines() -> list[tuple[str, bool, str]]:
            listed = client.get("/api/machines", headers=auth(key)).json()
            return [(m["name"], m["online"], m["last_error"]) for m in listed]

        wait_for("every machine online", lambda: all(m[1] for m in machines()), describe=machines)
        assert sorted(m[0] for m in machines()) == sorted(m.name for m in shop.machines)

        def agents() -> dict[str, str]:
            listed = client.get("/api/machines", headers=auth(key)).json()
            return {m["name"]: m["state"] for m in listed if m["kind"] in ("mtconnect", "opcua")}

        # every device of the agent and every machine tool of the OPC UA server is read, each
        # as its own machine, from its scripted cycle
        working = {"ready", "running", "stopped", "alarm"}
        wait_for(
            "the agent's and the OPC UA server's machines",
            lambda: len(agents()) == 4 and set(agents().values()) <= working,
            describe=agents,
        )
