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


def test_the_docs_show_the_prompting_reports_study_table():
    """The docs' study table is the one `bench report reports/data/prompting` wrote, to the cell."""
    report = study_block((ROOT / "reports" / "prompting.md").read_text())
    assert report.startswith("| model | prompt |")
    for page in ("docs/prompting.md",):
        assert study_block((ROOT / page).read_text()) == report, f"{page}: copy the study table from reports/prompting.md"


def test_the_readme_headline_table_agrees_with_the_study_report():
    """Each success the README's headline table quotes is the study report's, row by row."""
    rows = {}
    for line in study_block((ROOT / "reports" / "prompting.md").read_text()).splitlines()[2:]:
        cells = [c.strip() for c in line.strip("|").split("|")]
        rows[(cells[0], cells[1])] = cells
    readme = (ROOT / "README.md").read_text()
    headline = readme[readme.index("| model | paper's prompt: success"):]
    headline = headline[:headline.index("\n\n")]
    near, near_exact = "nearest-only (K 3, demonstrations, l2)", "nearest-only (K 3, demonstrations, l2) (exact history)"
    expected = {"Qwen2.5-Coder 1.5B": (("Qwen2.5-Coder 1.5B", "chronological"), ("Qwen2.5-Coder 1.5B", near)),
                "Qwen2.5-Coder 0.5B": (("Qwen2.5-Coder 0.5B", "chronological"), ("Qwen2.5-Coder 0.5B", near_exact)),
                "Gemma 3 270M (embedded default)": (("Gemma 3 270M", "chronological"), ("Gemma 3 270M", near))}
    for line in headline.splitlines()[2:]:
        cells = [c.strip().replace("**", "") for c in line.strip("|").split("|")]
        if cells[0] not in expected:
            continue
        paper, retrieval = expected.pop(cells[0])
        assert cells[1] == rows[paper][5], (cells[0], "paper's prompt")
        assert cells[3] == rows[retrieval][5], (cells[0], "nearest-only")
        if rows[retrieval][3] != "-":  # the probe's gain, rounded to two places
            gain = float(rows[retrieval][3].split()[0])
            assert cells[4].split(" / ")[1].startswith(f"{gain:.2f}"), (cells[0], cells[4], gain)
    assert not expected, f"rows missing from the README's headline table: {list(expected)}"
