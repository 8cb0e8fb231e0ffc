"""Colours people must tell apart, read from the stylesheets the pages ship: text at least
4.5:1 against its background (WCAG 2.1, 1.4.3), and in the timelines "ready" at least 3:1
against "no record" (1.4.11: they were nearly the same light grey). Line numbers in the
listing and the editor were 2.9:1."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

STATIC = Path(__file__).resolve().parents[2] / "src" / "opendnc" / "server" / "web" / "static"


def _css(name: str) -> str:
    return (STATIC / name).read_text(encoding="utf-8")


def _rule(css: str, selector: str) -> str:
    found = re.search(re.escape(selector) + r"[^{]*\{([^}]*)\}", css)
    assert found, selector
    return found.group(1)


def _colour(block: str, prop: str) -> str:
    found = re.search(rf"(?:^|[;\s]){re.escape(prop)}:\s*(#[0-9a-fA-F]{{6}})", block)
    assert found, (prop, block)
    return found.group(1)


def _luminance(hex_colour: str) -> float:
    def channel(c: int) -> float:
        v = c / 255
        return v / 12.92 if v <= 0.03928 else ((v + 0.055) / 1.055) ** 2.4

    r, g, b = (int(hex_colour[i : i + 2], 16) for i in (1, 3, 5))
    return 0.2126 * channel(r) + 0.7152 * channel(g) + 0.0722 * channel(b)


def contrast(a: str, b: str) -> float:
    """The WCAG contrast ratio of two colours."""
    hi, lo = sorted((_luminance(a), _luminance(b)), reverse=True)
    return (hi + 0.05) / (lo + 0.05)


def test_the_contrast_formula_knows_black_on_white() -> None:
    assert contrast("#000000", "#ffffff") == pytest.approx(21.0)
    assert contrast("#777777", "#ffffff") == pytest.approx(4.48, abs=0.01)


def test_line_numbers_are_readable_in_the_listing_and_the_editor() -> None:
    listing = _css("listing.css")
    number = _colour(_rule(listing, ".listing-box td.no a, .listing-box .no"), "color")
    gutter = _colour(_rule(listing, ".listing-box .ln .no"), "background")
    assert contrast(number, gutter) >= 4.5, (number, gutter)
    block = _colour(_rule(listing, ".w-blk"), "color")
    assert contrast(block, "#ffffff") >= 4.5
    editor = _rule(_css("workbench.css"), ".ed .cm-gutters ")
    assert contrast(_colour(editor, "color"), _colour(editor, "background")) >= 4.5


def test_ready_and_no_record_are_told_apart_in_both_timelines() -> None:
    app = _css("app.css")
    ready = _colour(_rule(app, ".state-ready, .ready, .tl-ready"), "--state")
    assert contrast(ready, _colour(_rule(app, ".tl-no_record"), "fill")) >= 3.0
    assert (
        contrast(
            _colour(_rule(app, ".st-ready"), "fill"), _colour(_rule(app, ".st-no_record"), "fill")
        )
        >= 3.0
    )
