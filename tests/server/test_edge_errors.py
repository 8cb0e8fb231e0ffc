"""The API's net under its own bounds: a number PostgreSQL cannot store is the client's 422,
any other data error from the driver is the server's 500 (docs/server.md, errors)."""

from __future__ import annotations

import asyncio
import json

import pytest
from sqlalchemy import Engine, text
from sqlalchemy.exc import DataError
from starlette.requests import Request

from opendnc.server.http.edge import _data_error
from tests.server.conftest import on


def _error_of(engine: Engine, sql: str) -> DataError:
    with pytest.raises(DataError) as caught, engine.connect() as conn:
        conn.execute(text(sql))
    return caught.value


def _answer(exc: DataError) -> tuple[int, str]:
    request = Request({"type": "http", "method": "GET", "path": "/api/jobs/1", "headers": []})
    reply = asyncio.run(_data_error(request, exc))
    return reply.status_code, json.loads(bytes(reply.body))["detail"]


@on("postgresql")
def test_a_number_postgresql_cannot_store_is_the_clients_422(engine: Engine) -> None:
    status, detail = _answer(_error_of(engine, "SELECT CAST(2147483648 AS integer)"))
    assert (status, detail) == (422, "a number in the request is out of range")


@on("postgresql")
def test_another_data_error_stays_the_servers_500(engine: Engine) -> None:
    status, detail = _answer(_error_of(engine, "SELECT CAST('twelve' AS integer)"))
    assert status == 500
    assert "internal error" in detail
