"""The HTML report in headless Chromium: renders, no console errors, no network request."""

from __future__ import annotations

import subprocess
from pathlib import Path

from opendnc.surface.points import PointRow, PointsWriter
from tests.peers import require_command, require_module

from .conftest import CLI, GRID, surface

CHROMIUM = "/usr/bin/chromium"
ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-default-apps",
    "--disable-sync",
    "--no-first-run",
    "--metrics-recording-only",
    "--disable-features=Translate,OptimizationHints,MediaRouter",
]


def write_points(path: Path) -> None:
    with PointsWriter(path, GRID) as writer:
        for p in GRID.points:
            if p.number == 20:
                continue  # one missing point: the report must say so
            z = f"{surface(p.x, p.y) + (0.004 if p.number == 33 else 0.0):.4f}"
            writer.write(PointRow(p.number, p.row, p.col, p.x, p.y, float(z), z, "", ""))


def test_report_opens_offline_in_chromium(tmp_path: Path) -> None:
    require_command("chromium")
    sync_api = require_module("playwright.sync_api")
    points = tmp_path / "points.csv"
    write_points(points)
    html = tmp_path / "report.html"
    made = subprocess.run(
        [*CLI, "surface", "report", str(points), "-o", str(html), "--png", str(tmp_path / "m.png")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert made.returncode == 0, made.stderr
    page_url = html.as_uri()
    errors: list[str] = []
    requests: list[str] = []
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            page = browser.new_page()
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.on(
                "request",
                lambda r: (
                    requests.append(r.url)
                    if r.url != page_url and not r.url.startswith("data:")
                    else None
                ),
            )
            page.goto(page_url)
            page.wait_for_selector("#surface3d .main-svg", timeout=30_000)
            text = page.inner_text("body")
            traces = page.evaluate("document.getElementById('surface3d').data.length")
            image_ok = page.evaluate(
                "(() => { const i = document.querySelector('img'); "
                "return i.complete && i.naturalWidth > 500; })()"
            )
        finally:
            browser.close()
    assert errors == []
    assert requests == []
    assert traces == 2  # the surface and the points
    assert image_ok
    assert "Missing points\t20" in text
    assert "Flatness (peak to valley after plane removal)" in text
    assert "arc-seconds" in text
    assert "33" in text.split("Outliers")[-1]  # the raised point is listed as an outlier
