"""A program's title: known headers give known titles, and any bytes give a short one-line
text without failing (hypothesis)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from opendnc.server.library.titles import HEAD, MAX_TITLE, title_of


@pytest.mark.parametrize(
    ("text", "title"),
    [
        (b"%\nO1000 (BRACKET OP1)\nG0 X0\n%\n", "BRACKET OP1"),
        (b"%\r\nO01234(  PLATE  --  SIDE 2 )\r\nT1 M6\r\n", "PLATE -- SIDE 2"),
        (b"\n\n:2000 (ALT O WORD)\n", "ALT O WORD"),
        (b"O1000\n(NOT ON THE O LINE)\n", ""),
        (b"N10 O3000 (WITH A BLOCK NUMBER)\n", "WITH A BLOCK NUMBER"),
        (b"O4000 (UNCLOSED\n", "UNCLOSED"),
        (
            b"0 BEGIN PGM POCKET MM\r\n1 ; POCKET FOR THE BRACKET\r\n2 END PGM POCKET MM\r\n",
            "POCKET FOR THE BRACKET",
        ),
        (b"0 BEGIN PGM POCKET MM\r\n1 BLK FORM 0.1 Z X+0\r\n", "POCKET"),
        (b"0  BEGIN PGM 123 INCH\n1 ;\n", "123"),
        (
            b"G0 X0 Y0\nO1000 (TOO LATE? NO: WITHIN THE FIRST LINES)\n",
            "TOO LATE? NO: WITHIN THE FIRST LINES",
        ),
        (b"G0 X0\nG1 X1\nG1 X2\nO1000 (AFTER THREE LINES)\n", ""),
        (b"", ""),
        (b"\x00\x01\x02", ""),
    ],
)
def test_known_titles(text: bytes, title: str) -> None:
    assert title_of(text) == title


def test_a_long_comment_is_cut() -> None:
    assert title_of(b"O1 (" + b"A" * 300 + b")\n") == "A" * MAX_TITLE


def test_a_line_cut_at_the_head_is_not_read() -> None:
    head = (b"%\n" + b"(" + b"X" * HEAD + b")\n")[:HEAD]
    assert title_of(head) == ""


@given(st.binary(max_size=3 * HEAD))
def test_any_bytes_give_a_short_line(data: bytes) -> None:
    title = title_of(data[:HEAD])
    assert len(title) <= MAX_TITLE
    assert "\n" not in title
    assert "\r" not in title
    assert title == title.strip()


@given(
    st.text(
        alphabet=st.characters(min_codepoint=32, max_codepoint=126, blacklist_characters="()"),
        max_size=60,
    )
)
def test_the_o_line_comment_comes_back(comment: str) -> None:
    expected = " ".join(comment.split())[:MAX_TITLE].rstrip()
    assert title_of(f"%\nO1000 ({comment})\nG0 X0\n".encode()) == expected
