"""PLC operand notation and addresses, table parsing, and the generated blocking facade."""

from __future__ import annotations

import inspect

import pytest

from opendnc.errors import InputError, RemoteProtocolError
from opendnc.lsv2 import AsyncClient, Client
from opendnc.lsv2.constants import MemoryType
from opendnc.lsv2.plc import PlcOperand, decode_values, parse_operand, plan_reads
from opendnc.lsv2.tables import Table, fixed_columns, parse_table
from tests.unit.lsv2.samples import PARAMS


@pytest.mark.parametrize(
    ("text", "memory", "index"),
    [
        ("M100", MemoryType.MARKER, 100),
        ("i5", MemoryType.INPUT, 5),
        ("E5", MemoryType.INPUT, 5),
        ("O3", MemoryType.OUTPUT, 3),
        ("C2", MemoryType.COUNTER, 2),
        ("T7", MemoryType.TIMER, 7),
        ("B10", MemoryType.BYTE, 10),
        ("W4", MemoryType.WORD, 2),
        ("D16", MemoryType.DWORD, 4),
        ("S3", MemoryType.STRING, 3),
        ("IW2", MemoryType.INPUT_WORD, 1),
        ("OW4", MemoryType.OUTPUT_WORD, 2),
        ("ID8", MemoryType.INPUT_DWORD, 2),
        ("OD0", MemoryType.OUTPUT_DWORD, 0),
    ],
)
def test_operand_notation(text: str, memory: MemoryType, index: int) -> None:
    op = parse_operand(text)
    assert op == PlcOperand(memory, index)
    assert parse_operand(op.notation) == op


@pytest.mark.parametrize("bad", ["W3", "D6", "X1", "M", "M-1", "IW1", ""])
def test_bad_operands(bad: str) -> None:
    with pytest.raises(InputError):
        parse_operand(bad)


def test_addresses_from_golden_parameters() -> None:
    # TNC 320 v18 layout (docs/lsv2.md#system-parameters): markers 122064, words 64, strings 165208
    # × 240 bytes
    assert plan_reads(MemoryType.MARKER, 0, 1, PARAMS) == [(122064, 1)]
    assert plan_reads(MemoryType.WORD, 2, 1, PARAMS) == [(68, 2)]
    assert plan_reads(MemoryType.DWORD, 4, 1, PARAMS) == [(80, 4)]
    assert plan_reads(MemoryType.STRING, 1, 1, PARAMS) == [(165448, 240)]
    assert plan_reads(MemoryType.INPUT_WORD, 1, 1, PARAMS) == [(120066, 2)]
    assert plan_reads(MemoryType.OUTPUT_DWORD, 1, 1, PARAMS) == [(121068, 4)]
    reads = plan_reads(MemoryType.MARKER, 10, 600, PARAMS)
    assert [n for _, n in reads] == [255, 255, 90]
    assert reads[1][0] == 122064 + 10 + 255
    words = plan_reads(MemoryType.WORD, 0, 200, PARAMS)
    assert all(n % 2 == 0 and n <= 255 for _, n in words)
    assert sum(n for _, n in words) == 400
    assert len(plan_reads(MemoryType.STRING, 0, 3, PARAMS)) == 3
    with pytest.raises(InputError, match="outside"):
        plan_reads(MemoryType.TIMER, 999, 2, PARAMS)


def test_decode_values_little_endian() -> None:
    assert decode_values(MemoryType.WORD, b"\xfe\xff\x01\x00", 2, PARAMS) == [-2, 1]
    assert decode_values(MemoryType.INPUT_WORD, b"\xfe\xff", 1, PARAMS) == [65534]
    assert decode_values(MemoryType.MARKER, b"\x00\x02", 2, PARAMS) == [False, True]
    assert decode_values(MemoryType.STRING, b"ab\0" + bytes(237), 1, PARAMS) == ["ab"]
    with pytest.raises(RemoteProtocolError):
        decode_values(MemoryType.DWORD, b"\x00", 1, PARAMS)


TOOL_T = (
    "BEGIN TOOL.T MM\r\n"
    "T    NAME             L           R           DOC\r\n"
    "0    NULLWERKZEUG     +0          +0          zero tool\r\n"
    "1    MILL_D10         +65.5       +5          end mill 10\r\n"
    "2                                              \r\n"
    "[END]\r\n"
)


def test_table_parse_types_and_round_trip() -> None:
    t = parse_table(TOOL_T)
    assert (t.name, t.unit) == ("TOOL.T", "MM")
    assert t.column_names == ["T", "NAME", "L", "R", "DOC"]
    rows = t.typed_rows()
    assert rows[1] == {"T": 1, "NAME": "MILL_D10", "L": 65.5, "R": 5, "DOC": "end mill 10"}
    assert rows[2]["NAME"] is None
    assert parse_table(t.to_text()).rows == t.rows
    assert t.to_text().splitlines()[:3] == TOOL_T.splitlines()[:3]
    assert t.to_csv().splitlines()[2] == "1,MILL_D10,+65.5,+5,end mill 10"


def test_table_with_struct_block() -> None:
    text = "BEGIN TOOL.T MM\n#STRUCTBEGIN\nT N\n#STRUCTEND\nT  NAME\n1  A\n[END]\n"
    t = parse_table(text)
    assert t.preamble == ["#STRUCTBEGIN", "T N", "#STRUCTEND"]
    assert t.rows == [{"T": "1", "NAME": "A"}]


@pytest.mark.parametrize("bad", ["", "hello\n", "BEGIN X.T\n", "BEGIN X.T\nT N\n1 a\n"])
def test_bad_tables(bad: str) -> None:
    with pytest.raises(InputError):
        parse_table(bad)


def test_facades_offer_the_same_methods() -> None:
    def public(cls: type) -> set[str]:
        return {n for n in dir(cls) if not n.startswith("_")}

    assert public(Client) == public(AsyncClient)
    for name in public(AsyncClient):
        attr = getattr(AsyncClient, name)
        if inspect.iscoroutinefunction(attr):
            assert not inspect.iscoroutinefunction(getattr(Client, name)), name


def test_fixed_columns_lay_out_a_new_table() -> None:
    columns = fixed_columns(("T", 4), ("NAME", 8), ("L", 6))
    assert [(c.start, c.width) for c in columns] == [(0, 4), (4, 8), (12, 6)]
    text = Table("BEGIN TOOL.T MM", columns, [{"T": "1", "NAME": "MILL", "L": "+5"}]).to_text()
    assert text == "BEGIN TOOL.T MM\r\nT   NAME    L\r\n1   MILL    +5\r\n[END]\r\n"
    assert parse_table(text).rows == [{"T": "1", "NAME": "MILL", "L": "+5"}]
