"""The virtual MTConnect agent over real HTTP: its probe is valid by the Institute's schema,
it answers current and sample as an agent does (OUT_OF_RANGE, NO_DEVICE, a new instance after
a restart), and its stream carries heartbeats when nothing changes."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from typing import Any

import pytest

from tests.peers import require_module, require_reference

httpx = require_module("httpx")
require_module("uvicorn")
require_module("lxml")

from opendnc.mtconnect.documents import (  # noqa: E402
    AgentRefused,
    parse_devices,
    parse_document,
    parse_streams,
)
from opendnc.mtconnect.multipart import MultipartSplitter, boundary_of  # noqa: E402
from opendnc.sim.mtconnect.agent import VirtualAgent  # noqa: E402
from opendnc.sim.mtconnect.machine import ScriptedMachine  # noqa: E402

_SCHEMAS: dict[str, Any] = {}


def _schema(version: str) -> Any:
    xmlschema = require_module("xmlschema")
    if version not in _SCHEMAS:
        path = require_reference(f"mtconnect-schema/MTConnectDevices_{version}.xsd")
        _SCHEMAS[version] = xmlschema.XMLSchema11(str(path))
    return _SCHEMAS[version]


async def _agent(names: list[str], **options: Any) -> VirtualAgent:
    agent = VirtualAgent(names, **options)
    await agent.start()
    return agent


async def _stream(client: Any, url: str, limit: int) -> AsyncIterator[bytes]:
    async with client.stream("GET", url) as answer:
        boundary = boundary_of(answer.headers["content-type"])
        assert boundary is not None
        splitter = MultipartSplitter(boundary)
        taken = 0
        async for chunk in answer.aiter_bytes():
            for part in splitter.feed(chunk):
                yield part
                taken += 1
                if taken >= limit:
                    return


def test_the_probe_is_valid_by_the_schema_it_declares() -> None:
    async def main() -> bytes:
        agent = await _agent(["mill-1", "lathe 2", "Ünï.cöde"])
        try:
            async with httpx.AsyncClient() as client:
                return (await client.get(f"{agent.url}/probe")).content
        finally:
            await agent.close()

    probe = asyncio.run(main())
    devices = parse_devices(probe)
    assert [d.name for d in devices.devices] == ["mill-1", "lathe 2", "Ünï.cöde"]
    errors = [str(e).splitlines()[0] for e in _schema("2.0").iter_errors(probe.decode())]
    assert errors == []


def test_current_sample_and_the_agents_refusals() -> None:
    async def main() -> None:
        agent = await _agent(["m1", "m2"], buffer_size=8)
        machine = ScriptedMachine(agent, "m1")
        try:
            async with httpx.AsyncClient() as client:
                current = parse_streams((await client.get(f"{agent.url}/m1/current")).content)
                # every value starts UNAVAILABLE, as an agent's do before the adapter speaks
                values = {o.data_item_id: o.value for o in current.observations}
                assert values["d1_exec"] == "UNAVAILABLE"
                assert {o.device for o in current.observations} == {"m1"}
                machine.power_on(parts=5)
                machine.start("O77")
                current = parse_streams((await client.get(f"{agent.url}/current")).content)
                values = {o.data_item_id: o.value for o in current.observations}
                assert (values["d1_exec"], values["d1_parts"], values["d1_program"]) == (
                    "ACTIVE",
                    "5",
                    "O77",
                )
                assert values["d2_exec"] == "UNAVAILABLE"
                # a device's own probe names the items its streams carry
                probe = parse_devices((await client.get(f"{agent.url}/m2/probe")).content)
                second = parse_streams((await client.get(f"{agent.url}/m2/current")).content)
                assert [d.name for d in probe.devices] == ["m2"]
                declared = {i.id for i in probe.devices[0].items}
                assert {o.data_item_id for o in second.observations} == declared
                # the buffer of 8 has rolled: from=1 has left it
                answer = await client.get(f"{agent.url}/sample", params={"from": "1"})
                assert answer.status_code == 400
                with pytest.raises(AgentRefused) as caught:
                    parse_document(answer.content)
                assert caught.value.codes == ("OUT_OF_RANGE",)
                head = current.header
                sample = parse_streams(
                    (
                        await client.get(
                            f"{agent.url}/sample",
                            params={"from": str(head.first_sequence), "count": "3"},
                        )
                    ).content
                )
                assert len(sample.observations) <= 3
                assert sample.header.next_sequence == head.first_sequence + 3
                answer = await client.get(f"{agent.url}/nope/current")
                with pytest.raises(AgentRefused, match="NO_DEVICE"):
                    parse_document(answer.content)
        finally:
            await agent.close()

    asyncio.run(main())


def test_the_stream_sends_changes_heartbeats_and_a_new_instance_after_a_restart() -> None:
    async def main() -> None:
        agent = await _agent(["m1"])
        machine = ScriptedMachine(agent, "m1")
        machine.power_on()
        url = f"{agent.url}/sample?interval=10&heartbeat=100&from={agent.first_sequence}"
        try:
            async with httpx.AsyncClient(timeout=5) as client:
                parts = _stream(client, url, 10)
                first = parse_streams(await anext(parts))
                assert any(o.value == "AVAILABLE" for o in first.observations)
                heartbeat = parse_streams(await anext(parts))  # nothing changed: empty
                assert heartbeat.observations == ()
                machine.start("O5")
                changed = parse_streams(await anext(parts))
                assert "O5" in {o.value for o in changed.observations}
                await parts.aclose()
                instance = first.header.instance_id
                await agent.restart()
                current = parse_streams((await client.get(f"{agent.url}/current")).content)
                assert current.header.instance_id != instance
                assert current.header.first_sequence == 1
                values = {o.data_item_id: o.value for o in current.observations}
                assert values["d1_program"] == "O5"  # every value resent after the restart
        finally:
            await agent.close()

    asyncio.run(main())
