"""This computer's zone name, as `opendnc demo` takes it for the shop's clock: from TZ, the
/etc/localtime link into the zone database, or /etc/timezone; UTC when none names a zone."""

from __future__ import annotations

from pathlib import Path

from opendnc.server.core.host_zone import host_zone_name


def _database(tmp_path: Path, name: str) -> Path:
    # a zone database's file for ``name`` (the link's target: only its path is read)
    path = tmp_path / "usr" / "share" / "zoneinfo" / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"TZif")
    return path


def test_tz_comes_first_as_a_name_or_a_path(tmp_path: Path) -> None:
    none = tmp_path / "absent"
    assert host_zone_name({"TZ": "Asia/Tokyo"}, none, none) == "Asia/Tokyo"
    assert host_zone_name({"TZ": ":Europe/Berlin"}, none, none) == "Europe/Berlin"
    path = _database(tmp_path, "America/Chicago")
    assert host_zone_name({"TZ": f":{path}"}, none, none) == "America/Chicago"


def test_the_localtime_link_then_the_timezone_file(tmp_path: Path) -> None:
    link = tmp_path / "localtime"
    link.symlink_to(_database(tmp_path, "Europe/Berlin"))
    named = tmp_path / "timezone"
    named.write_text("Australia/Sydney\n")
    assert host_zone_name({}, link, named) == "Europe/Berlin"
    # a TZ that names no zone (a POSIX rule, a typo) is passed over
    assert host_zone_name({"TZ": "CET-1CEST"}, link, named) == "Europe/Berlin"
    assert host_zone_name({"TZ": "Mars/Olympus"}, link, named) == "Europe/Berlin"
    assert host_zone_name({}, tmp_path / "no-link", named) == "Australia/Sydney"


def test_utc_when_nothing_names_a_zone(tmp_path: Path) -> None:
    odd = tmp_path / "timezone"
    odd.write_text("../../etc/passwd\n")
    not_a_zone = tmp_path / "localtime"
    not_a_zone.write_text("plain file")
    assert host_zone_name({}, not_a_zone, odd) == "UTC"
    assert host_zone_name({}, tmp_path / "none", tmp_path / "none") == "UTC"
