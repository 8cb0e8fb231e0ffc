"""A card's glance: the shift's parts against its ``[goals]`` goal with what is expected by
now, and today so far, read from the same report function as the utilization page (one
state, both rendered, the same words). The timeline is :mod:`tests.web.utilization_shop`'s;
the expected figures are worked out by hand from it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from sqlalchemy.orm import Session, sessionmaker

from opendnc.server import actions
from opendnc.server.config.shop import parse_config
from opendnc.server.core.configkeys import ConfigError
from opendnc.server.machines.state import MachineState
from opendnc.server.store.db import read_only
from opendnc.server.store.models import Role
from opendnc.server.utilization.collect import Group
from opendnc.server.web import render
from opendnc.server.web.pages.floor import glance_words
from opendnc.server.web.pages.utilization import percent_text
from tests.server.actions_support import StillRunner
from tests.server.conftest import on
from tests.web.utilization_shop import CONFIG, local, write_timeline

GOALS = """
[goals]
"mill-1" = { shift = 40 }
"vf2-long-name-1" = { day = 90 }
"""
NOW = local(10)  # Monday 10:00, four hours into the early shift (06-14)


def _value(html: str, key: str, name: str) -> str:
    return html.split(f'data-{key}="{name}">', 1)[1].split("<", 1)[0]


@on("sqlite")
def test_the_card_and_the_utilization_page_say_the_same(
    sessions: sessionmaker[Session], tmp_path: Path
) -> None:
    config = parse_config(CONFIG + GOALS, base=tmp_path)
    write_timeline(sessions)
    runner = StillRunner(config, {m.name: MachineState(m) for m in config.machines})
    svc = actions.Services(sessions, read_only(sessions), runner)
    who = actions.Caller("viewer", Role.VIEWER)
    names = [m.name for m in config.machines]
    glances = actions.utilization.floor_glance(svc, who, names, NOW)
    cards = "".join(render.render("_glance.html", g=g, **glance_words()) for g in glances.values())

    # by hand: mill-1's goal is 40 a shift, 20 of them due after 4 of its 8 hours; it ran
    # once (07-09, then ready). vf2's 90 a day spread over Monday's 18 shift hours (06-24):
    # 40 in the early shift, 20 due by 10:00; 8 cycles of 06:00-10:00 ended (the counter).
    shift = {
        n: (g.shift_oee.made, g.shift_oee.goal, g.shift_oee.expected)
        for n, g in glances.items()
        if g.shift_oee is not None
    }
    assert shift["mill-1"] == (1, 40, 20)
    assert shift["vf2-long-name-1"] == (8, 40, 20)
    assert shift["lathe-3"][1:] == (None, None)  # no goal, no standard time
    assert re.search(r'data-shift-parts="vf2-long-name-1">.*<strong>8</strong> of 40 parts', cards)
    assert '20 expected by now · <strong class="behind-text">12 behind</strong>' in cards
    # today so far: mill-1 ran 07-09 of 06-10's shift time (50 %), vf2 8 x 20 min (66.7 %);
    # each goal is the whole day's: mill-1 40 + 40 + the night's first 2 of 8 hours (10)
    assert _value(cards, "util", "mill-1") == "50.0 %"
    assert _value(cards, "util", "vf2-long-name-1") == "66.7 %"
    assert _value(cards, "ran-today", "vf2-long-name-1") == "2:40"
    assert _value(cards, "parts", "mill-1") == "1 / 90"
    assert _value(cards, "parts", "vf2-long-name-1") == "8 / 90"

    # the utilization page of today, from the same state
    today = config.calendar.local(NOW).date()
    r = actions.utilization.days_report(svc, who, today, today, Group.DAY, names, NOW)
    page = render.render(
        "utilization.html", page=None, path="/utilization", roles=[], report=r, floor=r.floor,
        zone="", zone_name="", zone_label="", first="", last="", group="day", query="",
        rows=[], shown_pct=100, ticks=[], bars={}, states=[], percent=percent_text,
        duration=lambda s: "", clock=lambda at: "", shifts=config.calendar.shifts,
        span_label="", stops=[], alarms=[], reason_of=lambda m, s: "",
        fraction=lambda v: percent_text(None if v is None else 100.0 * v),
    )  # fmt: skip
    for name in names:
        for key in ("util", "oee", "parts"):
            assert _value(cards, key, name) == _value(page, key, name), (name, key)


@pytest.mark.parametrize(
    ("goals", "key"),
    [
        ('"nobody" = { shift = 3 }', "goals.nobody"),
        ('"mill-1" = { shift = 0 }', "goals.mill-1.shift"),
        ('"mill-1" = { week = 3 }', "goals.mill-1"),
        ('"mill-1" = { shift = { noon = 3 } }', "goals.mill-1.shift.noon"),
    ],
)
def test_a_bad_goal_names_its_key(goals: str, key: str, tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as caught:
        parse_config(CONFIG + "\n[goals]\n" + goals + "\n", base=tmp_path)
    assert caught.value.key == key


def test_a_goal_per_shift_needs_shifts(tmp_path: Path) -> None:
    text = CONFIG.split("[[shifts]]")[0] + CONFIG.split('end = "06:00"')[1]
    with pytest.raises(ConfigError, match="needs"):
        parse_config(text + '\n[goals]\n"mill-1" = { shift = 3 }\n', base=tmp_path)
    # a day's goal in a shop without shifts: the whole day is planned
    config = parse_config(text + '\n[goals]\n"mill-1" = { day = 48 }\n', base=tmp_path)
    goal = config.goals.of("mill-1")
    assert goal is not None
    assert goal.over(config.calendar, local(0), local(6)) == pytest.approx(12.0)
