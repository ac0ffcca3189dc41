"""The leaderboard as one self-contained HTML page: no network at view time, nothing to install.

Models as rows, reference controllers set apart below them; every column sorts (click a header, or
open the page with `#sort=KEY&dir=asc|desc`); each score shows its 95% interval; a bar chart per
metric and the probe's per-joint error are inline SVG; each row unfolds into its exact settings,
versions and the command that regenerates it.
"""

from __future__ import annotations

import html
import json

import numpy as np

from benchmark.evaluate.scorecard import on_some_cells, row_label, row_strategy, trivial_gain
from robots import CANONICAL_JOINTS

COLUMNS = (  # key, heading, kind ("text" or "number")
    ("model", "model", "text"), ("strategy", "prompt strategy", "text"), ("kind", "kind", "text"),
    ("params", "params", "text"), ("tier", "tier", "text"),
    ("skill", "probe skill [95%]", "number"), ("gain", "gain over the prompt's trivial answer [95%]", "number"),
    ("error", "probe error", "number"),
    ("within", "within 1 step", "number"), ("failures", "parse failures", "number"),
    ("latency", "s / query", "number"), ("nwt", "closed-loop NWT", "number"), ("success", "success", "number"),
)
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
           "#17becf")

STYLE = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2rem auto;max-width:1200px;color:#222}
table{border-collapse:collapse;width:100%;font-size:14px}th,td{padding:4px 8px;border-bottom:1px solid #ddd;text-align:left}
th{cursor:pointer;background:#f4f4f4;position:sticky;top:0}th.sorted-asc::after{content:" \\25B2"}
th.sorted-desc::after{content:" \\25BC"}tr.reference td{background:#f7f7fb;color:#555;font-style:italic}
tr.reference:first-of-type td,tr.first-reference td{border-top:3px double #99a}
.ci{color:#777;font-size:12px}details{font-size:12px}pre{white-space:pre-wrap;background:#fafafa;padding:6px}
.charts{display:flex;flex-wrap:wrap;gap:1.5rem}.chart h3{font-size:14px;margin:.2rem 0}
"""

SCRIPT = """
function sortBy(key, dir){
  const body=document.querySelector('#board tbody');
  const rows=[...body.querySelectorAll('tr.row')];
  const num=document.querySelector('th[data-key="'+key+'"]').dataset.kind==='number';
  const value=r=>{const v=r.querySelector('td[data-key="'+key+'"]').dataset.value;return num?(v===''?NaN:parseFloat(v)):v;};
  const has=(r,c)=>r.classList.contains(c);
  const models=rows.filter(r=>!has(r,'reference')&&!has(r,'restricted')), some=rows.filter(r=>has(r,'restricted'));
  const refs=rows.filter(r=>has(r,'reference'));
  const cmp=(a,b)=>{const x=value(a),y=value(b);
    if(num){if(isNaN(x)&&isNaN(y))return 0;if(isNaN(x))return 1;if(isNaN(y))return -1;return dir==='asc'?x-y:y-x;}
    return dir==='asc'?String(x).localeCompare(String(y)):String(y).localeCompare(String(x));};
  models.sort(cmp);some.sort(cmp);refs.sort(cmp);
  for(const r of [...models,...some,...refs]){body.appendChild(r);const d=document.getElementById('details-'+r.id);if(d)body.appendChild(d);}
  refs.forEach((r,i)=>r.classList.toggle('first-reference',i===0));
  document.querySelectorAll('th').forEach(th=>th.classList.remove('sorted-asc','sorted-desc'));
  document.querySelector('th[data-key="'+key+'"]').classList.add('sorted-'+dir);
  document.body.dataset.sorted=key+':'+dir;
}
document.querySelectorAll('th[data-key]').forEach(th=>th.addEventListener('click',()=>{
  const dir=th.classList.contains('sorted-desc')?'asc':'desc';sortBy(th.dataset.key,dir);}));
const h=new URLSearchParams(location.hash.slice(1));
sortBy(h.get('sort')||'skill',h.get('dir')||'desc');
"""


def _row_values(row: dict, rows: list[dict]) -> dict:
    p = row["probe"]
    cells = row.get("closed_loop") or {}
    nwt = float(np.mean([c["nwt"] for c in cells.values()])) if cells else None
    success = float(np.mean([c["success"] for c in cells.values()])) if cells else None
    gain = trivial_gain(row, rows)
    return {"model": row_label(row), "strategy": row_strategy(row), "kind": row.get("kind", ""),
            "params": row.get("parameters") or "-", "tier": row["tier"],
            "skill": p["skill"], "skill_ci": (p["skill_low"], p["skill_high"]),
            "gain": None if gain is None else gain[1], "gain_ci": None if gain is None else (gain[2], gain[3], gain[0]),
            "error": p["error"],
            "within": p["within_step"], "failures": p["parse_failures"], "latency": p["latency_median_s"],
            "nwt": nwt, "success": success, "trials": sum(c["trials"] for c in cells.values()) if cells else 0}


def _cell(key: str, v: dict) -> str:
    value = v[key]
    if key == "skill":
        text = f"{value:.3f} <span class=ci>[{v['skill_ci'][0]:.3f}, {v['skill_ci'][1]:.3f}]</span>"
    elif key == "gain" and value is not None:
        low, high, over = v["gain_ci"]
        text = f"{value:+.3f} <span class=ci>[{low:+.3f}, {high:+.3f}] over {html.escape(over)}</span>"
    elif key == "success" and value is not None:
        text = f"{value:.2f} <span class=ci>({v['trials']} trials)</span>"
    elif isinstance(value, float):
        text = f"{value:.3f}" if key in ("error", "nwt") else f"{value:.2f}"
    else:
        text = html.escape(str(value)) if value is not None else "-"
    sort = "" if value is None else (f"{value:.6g}" if isinstance(value, (int, float)) else html.escape(str(value)))
    return f'<td data-key="{key}" data-value="{sort}">{text}</td>'


def _bars(title: str, items: list[tuple[str, float, tuple[float, float] | None]], lo: float, hi: float) -> str:
    """A horizontal bar chart in SVG: one bar per (label, value, interval)."""
    width, bar, left = 420, 16, 170
    height = 24 + bar * 1.5 * len(items)
    scale = lambda x: left + (width - left - 10) * (min(max(x, lo), hi) - lo) / (hi - lo)  # noqa: E731
    parts = [f'<svg width="{width}" height="{height:.0f}" role="img" aria-label="{html.escape(title)}">',
             f'<line x1="{scale(0 if lo < 0 else lo):.1f}" y1="10" x2="{scale(0 if lo < 0 else lo):.1f}" '
             f'y2="{height - 4:.0f}" stroke="#999"/>']
    for i, (label, value, ci) in enumerate(items):
        y = 14 + i * bar * 1.5
        x0, x1 = sorted((scale(max(lo, 0.0) if lo < 0 else lo), scale(value)))
        parts.append(f'<text x="{left - 6}" y="{y + bar * 0.75:.0f}" font-size="11" text-anchor="end">'
                     f'{html.escape(label)}</text>')
        parts.append(f'<rect x="{x0:.1f}" y="{y:.0f}" width="{max(x1 - x0, 1):.1f}" height="{bar}" '
                     f'fill="{PALETTE[i % len(PALETTE)]}" opacity="0.8"><title>{value:.3f}</title></rect>')
        if ci is not None:
            parts.append(f'<line x1="{scale(ci[0]):.1f}" x2="{scale(ci[1]):.1f}" y1="{y + bar / 2:.0f}" '
                         f'y2="{y + bar / 2:.0f}" stroke="#000" stroke-width="1.5"/>')
    parts.append("</svg>")
    return f'<div class=chart><h3>{html.escape(title)}</h3>{"".join(parts)}</div>'


def _joint_chart(rows: list[dict]) -> str:
    """Per-joint probe error, one line per row, joints in canonical order."""
    width, height, left, bottom = 640, 240, 40, 60
    series = [(row_label(r), r["probe"]["joint_error"]) for r in rows]
    top = max(max(e) for _, e in series) * 1.1 or 1.0
    xs = lambda j: left + j * (width - left - 20) / 11  # noqa: E731
    ys = lambda e: height - bottom - (height - bottom - 10) * e / top  # noqa: E731
    parts = [f'<svg width="{width}" height="{height}" role="img" aria-label="per-joint probe error">']
    for j, name in enumerate(CANONICAL_JOINTS):
        parts.append(f'<text x="{xs(j):.0f}" y="{height - bottom + 14}" font-size="10" text-anchor="end" '
                     f'transform="rotate(-45 {xs(j):.0f} {height - bottom + 14})">{name}</text>')
    for i, (label, errors) in enumerate(series):
        points = " ".join(f"{xs(j):.1f},{ys(e):.1f}" for j, e in enumerate(errors))
        color = PALETTE[i % len(PALETTE)]
        parts.append(f'<polyline points="{points}" fill="none" stroke="{color}" stroke-width="1.5">'
                     f'<title>{html.escape(label)}</title></polyline>')
        parts.append(f'<text x="{width - 150}" y="{14 + 12 * i}" font-size="10" fill="{color}">{html.escape(label)}'
                     f'</text>')
    parts.append(f'<text x="4" y="12" font-size="10">{top:.2f}</text></svg>')
    return ('<div class=chart><h3>Probe error per joint (action units; lower is better)</h3>'
            + "".join(parts) + "</div>")


def render(rows: list[dict], command: str) -> str:
    # models on every cell, then models on some cells (`bench eval --cells`: skills of other items), then references
    group = lambda r: 2 if r.get("kind") == "reference" else int(on_some_cells(r))  # noqa: E731
    ordered = sorted(rows, key=lambda r: (group(r), -r["probe"]["skill"]))
    values = [_row_values(r, rows) for r in ordered]
    head = "".join(f'<th data-key="{k}" data-kind="{kind}">{html.escape(h)}</th>' for k, h, kind in COLUMNS)
    body = []
    for r, v in zip(ordered, values):
        cls = ("row", "row restricted", "row reference")[group(r)]
        rid = html.escape(r["row_id"])
        body.append(f'<tr class="{cls}" id="{rid}">' + "".join(_cell(k, v) for k, _, _ in COLUMNS) + "</tr>")
        details = {k: r.get(k) for k in ("model", "kind", "file_sha256", "server_model", "suite", "suite_version",
                                          "tier", "probe_digest", "probe_settings", "closed_loop_settings",
                                          "versions", "git_commit", "fingerprint_id", "made_at", "wall_s")}
        body.append(f'<tr class="details" id="details-{rid}"><td colspan="{len(COLUMNS)}"><details><summary>'
                    f'settings, versions, command</summary><pre>{html.escape(json.dumps(details, indent=1))}</pre>'
                    f'<pre>{html.escape(r.get("command", ""))}</pre></details></td></tr>')
    skill = _bars("Probe skill (95% bootstrap interval)", [(v["model"], v["skill"], v["skill_ci"]) for v in values],
                  min(-0.2, min(v["skill"] for v in values)), 1.0)
    error = _bars("Probe error (action units)", [(v["model"], v["error"], None) for v in values], 0.0,
                  max(v["error"] for v in values) * 1.05 or 1.0)
    closed = [v for v in values if v["nwt"] is not None]
    charts = [skill, error]
    if closed:
        charts.append(_bars("Closed-loop NWT (mean over cells)", [(v["model"], v["nwt"], None) for v in closed], 0, 1))
    timed = [v for v in values if v["kind"] != "reference"]
    if timed:
        charts.append(_bars("Seconds per probe query (median)", [(v["model"], v["latency"], None) for v in timed], 0,
                            max(v["latency"] for v in timed) * 1.05 or 1.0))
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>promptwalk leaderboard</title>
<meta name="viewport" content="width=device-width, initial-scale=1"><style>{STYLE}</style></head>
<body data-sorted="">
<h1>promptwalk leaderboard</h1>
<p>LLMs as low-level controllers of legged robots. <b>Probe skill</b>: teacher-forced imitation of the seed policy on
the same items for every model, 1 - error / error of <code>hold</code> (hold 0, oracle 1, below 0 worse than
freezing); it measures imitation, not control. <b>Closed loop</b>: the paper's protocol (NWT and success over the
model's 10 s). Intervals are 95%. Reference controllers are set apart below the models, and a model scored on some cells only (its name says which) below those scored on all. Click a header to sort.</p>
<table id="board"><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>
<h2>Charts</h2><div class=charts>{''.join(charts)}{_joint_chart(ordered)}</div>
<p class=ci>Regenerate: <code>{html.escape(command)}</code>. Each row's own command is in its details.</p>
<script>{SCRIPT}</script>
</body></html>
"""
