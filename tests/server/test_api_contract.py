"""The API against its own OpenAPI document: schemathesis generates requests for every
operation from ``/openapi.json`` (valid and invalid: ids past 2^31, negative limits, odd
bytes) and checks that none answers 5xx, that every answer's status is documented, and that
its body and media type match the document. The server is the real one, on memory controls,
served on a loopback port; the checks run with an admin key (every operation is reachable)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.peers import require_module

schemathesis = require_module("schemathesis")
hypothesis = require_module("hypothesis")

from opendnc.server.library import versions as library  # noqa: E402
from opendnc.server.store.models import Role  # noqa: E402
from tests.server.inprocess_app import App, running  # noqa: E402

MACHINES: list[dict[str, object]] = [
    {"name": "tnc", "kind": "lsv2", "host": "127.0.0.1", "port": 1, "poll_interval": 0.2},
    {"name": "haas", "kind": "haas_serial", "serial": "socket://127.0.0.1:1", "dripfeed": True},
]


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[App]:
    with running(tmp_path_factory.mktemp("contract"), MACHINES) as app:
        with app.server.sessions.begin() as s:
            library.add_version(s, "O1.nc", b"%\nO1\nM30\n%\n", author="t")
            library.release(s, "O1.nc", 1, actor="t")
        yield app


@pytest.fixture(scope="module")
def api_schema(served: App) -> Any:
    # the server builds its document once, on the first request (seconds of CPU for every
    # route's models); asked here first, with room for a loaded machine, schemathesis's own
    # short read timeout meets the kept copy
    assert served.client.get("/openapi.json", timeout=120).status_code == 200
    schema = schemathesis.openapi.from_url(f"{served.client.base_url}/openapi.json")
    # never ends (a stream); revoking keys would revoke the test's own key (ids are small)
    return schema.exclude(path="/api/events").exclude(method="DELETE")


CHECKS = [
    schemathesis.checks.not_a_server_error,
    schemathesis.checks.status_code_conformance,
    schemathesis.checks.content_type_conformance,
    schemathesis.checks.response_schema_conformance,
]
EXAMPLES = 15  # per operation (about 30 operations)


def test_every_operation_answers_by_its_document(api_schema: Any, served: App) -> None:
    # schemathesis's own pytest plugin does not run under this pytest; its strategies do
    headers = served.api(Role.ADMIN)
    failures: list[str] = []
    operations = [result.ok() for result in api_schema.get_all_operations()]
    assert len(operations) > 25

    for operation in operations:

        @hypothesis.settings(
            max_examples=EXAMPLES,
            deadline=None,
            derandomize=True,
            database=None,
            suppress_health_check=list(hypothesis.HealthCheck),
        )
        @hypothesis.given(case=operation.as_strategy())
        def run(case: Any) -> None:
            case.call_and_validate(headers=headers, checks=CHECKS)

        try:
            run()
        except Exception as exc:  # every operation's failure, not only the first
            failures.append(f"{operation.label}: {str(exc)[:2000]}")
    assert not failures, "\n\n".join(failures)


def test_the_document_declares_bearer_keys_and_the_errors(served: App, tmp_path: Path) -> None:
    doc = served.client.get("/openapi.json").json()
    schemes = doc["components"]["securitySchemes"]
    assert [s["scheme"] for s in schemes.values()] == ["bearer"]
    upload = doc["paths"]["/api/programs/{name}"]["put"]
    assert list(upload["requestBody"]["content"]) == ["application/octet-stream"]
    assert set(upload["responses"]) >= {"201", "400", "401", "403", "404", "409", "413", "422"}
    content = doc["paths"]["/api/programs/{name}/versions/{number}/content"]["get"]
    assert list(content["responses"]["200"]["content"]) == ["application/octet-stream"]
    xml = doc["paths"]["/api/mtconnect/devices.xml"]["get"]
    assert list(xml["responses"]["200"]["content"]) == ["application/xml"]
    # every route that answers JSON names its schema (no bare "any object")
    for path, operations in doc["paths"].items():
        for method, op in operations.items():
            body = op["responses"].get("200") or op["responses"].get("201")
            media = body.get("content", {}) if body else {}
            if "application/json" in media:
                assert media["application/json"].get("schema"), (method, path)
            # a PUT route for every name with a folder would answer POST routes with 405
            assert "{name:path}" not in path
