"""The docs site builds with `mkdocs build --strict` (broken links and missing pages fail it); the pages that copy
a report's table hold it as the report wrote it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).parents[1]


def test_the_docs_site_builds_strict_and_holds_the_leaderboard(tmp_path):
    out = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                         cwd=ROOT, capture_output=True, text=True, timeout=300, env={"NO_MKDOCS_2_WARNING": "1",
                                                                                     **__import__("os").environ})
    assert out.returncode == 0, out.stderr[-3000:]
    site = tmp_path / "site"
    for page in ("index.html", "metrics/index.html", "models/index.html", "experiments/index.html",
                 "robots/index.html", "extending/index.html", "results/index.html", "reports/leaderboard/index.html",
                 "reports/leaderboard.html"):
        assert (site / page).is_file(), page
    assert "fonts.googleapis" not in (site / "index.html").read_text()  # the site works offline


def study_block(text: str) -> str:
    """The lines between a `<!-- study table ... -->` marker and `<!-- end of study table -->`."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("<!-- study table"))
    end = lines.index("<!-- end of study table -->")
    return "\n".join(lines[start + 1:end]).strip()


def test_the_readme_and_docs_show_the_prompting_reports_study_table():
    """The README's and docs' study table is the one `bench report reports/data/prompting` wrote, to the cell."""
    report = study_block((ROOT / "reports" / "prompting.md").read_text())
    assert report.startswith("| model | prompt |")
    for page in ("README.md", "docs/prompting.md"):
        assert study_block((ROOT / page).read_text()) == report, f"{page}: copy the study table from reports/prompting.md"
