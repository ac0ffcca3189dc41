"""The leaderboard page in a real browser (Debian's headless Chromium): it renders offline and sorts."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--no-first-run",
         "--disable-component-update", "--disable-sync", "--disable-quic"]
ROW = re.compile(r'<tr class="(row(?: reference| restricted)?)[^"]*" id="([0-9a-f]+)">(.*?)</tr>', re.S)
GROUPS = ("row", "row restricted", "row reference")  # all cells, some cells (`bench eval --cells`), references


@pytest.fixture(scope="module")
def page(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("board")
    made = subprocess.run([sys.executable, "-m", "benchmark.cli", "leaderboard", "--store",
                           str(ROOT / "reports" / "leaderboard"), "--out", str(out)], capture_output=True, text=True,
                          timeout=120)
    assert made.returncode == 0, made.stderr
    return out / "leaderboard.html"


def test_the_page_needs_no_network(page):
    text = page.read_text()
    assert not re.search(r'(src|href)="(https?:)?//', text), "the page loads something from the network"
    assert "<script>" in text and "<svg" in text


def _browser(page: Path, fragment: str, tmp_path: Path, *extra: str) -> str:
    if CHROMIUM is None:
        pytest.skip("Debian's chromium is not installed (apt-get install chromium; .ci/run installs it)")
    out = subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={tmp_path / 'profile'}", *extra,
                          f"file://{page}#{fragment}"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


def _column(dom: str, key: str) -> list[tuple[str, float]]:
    rows = []
    for cls, _, cells in ROW.findall(dom):
        value = re.search(rf'data-key="{key}" data-value="([^"]*)"', cells).group(1)
        rows.append((cls, float(value) if value else float("nan")))
    return rows


@pytest.mark.parametrize("key, direction", [("error", "asc"), ("skill", "desc"), ("within", "asc")])
def test_sorting_a_column_in_chromium_orders_models_then_references(page, tmp_path, key, direction):
    dom = _browser(page, f"sort={key}&dir={direction}", tmp_path, "--dump-dom")
    assert f'data-sorted="{key}:{direction}"' in dom  # the page's own script ran and sorted
    rows = _column(dom, key)
    assert len(rows) >= 4
    kinds = [cls for cls, _ in rows]
    assert kinds == sorted(kinds, key=GROUPS.index), kinds  # references below the models, restricted rows between
    for kind in GROUPS:
        values = [v for c, v in rows if c == kind]
        assert values == sorted(values, reverse=direction == "desc"), (kind, values)


def test_a_screenshot_of_the_page(page, tmp_path):
    shot = tmp_path / "leaderboard.png"
    _browser(page, "sort=skill&dir=desc", tmp_path, f"--screenshot={shot}", "--window-size=1280,1100")
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 20_000
