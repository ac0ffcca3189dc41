"""Small helpers every report uses: a pandas table as Markdown, the Wilson interval of a rate, the mean
seconds a query over trials that answered part of their queries from the reply cache, and which trials fell
before the takeover."""

from __future__ import annotations

import numpy as np
import pandas as pd


def wilson(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a rate: at 5 trials one fall moves the rate by 0.2."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def live_latency_mean(trials: pd.DataFrame) -> float:
    """Seconds a query over the trials' live (not cached) queries: each trial's `latency_mean_s` covers its live
    queries only, so it is weighted by their count (a trial replayed from the cache adds nothing). NaN where no
    query was live or no trial measured latency."""
    if "latency_mean_s" not in trials:
        return float("nan")
    latency = trials["latency_mean_s"].astype(float)
    if "queries" in trials:
        cached = trials["cache_hits"].fillna(0) if "cache_hits" in trials else 0
        live = (trials["queries"] - cached).astype(float).where(latency.notna(), 0.0).fillna(0.0)
    else:
        live = latency.notna().astype(float)
    return float((latency.fillna(0.0) * live).sum() / live.sum()) if live.sum() > 0 else float("nan")


def shared_machine(trials: pd.DataFrame) -> str:
    """' (shared: mean load L on C cores)' where a trial that queried live ran with the machine's load above its cores
    by half a core or more on average (other work ran beside it, so its latencies read high); "" otherwise or where
    the store has no core count (trials stored before it was recorded). Trials stored before the mean was recorded
    are judged on the load as they ended (' (shared: load L on C cores)')."""
    if not {"load_1m", "cores"} <= set(trials) or "latency_mean_s" not in trials:
        return ""
    live = trials[trials["latency_mean_s"].astype(float) > 0]
    mean = live["load_1m_mean"].astype(float) if "load_1m_mean" in live else pd.Series(np.nan, index=live.index)
    load = mean.fillna(live["load_1m"].astype(float))
    over = load[load > live["cores"].astype(float) + 0.5]
    if over.empty:
        return ""
    worst = over.idxmax()
    kind = "load" if np.isnan(mean[worst]) else "mean load"
    return f" (shared: {kind} {float(over[worst]):.1f} on {int(live.loc[worst, 'cores'])} cores)"


def ended_at_stop(trials: pd.DataFrame) -> int:
    """How many trials ended at their first stop (`--end-at-stop`): NWT and success exact, the rest of the episode
    (distance after the stop, a later fall, its replies) not run."""
    if "ended_at_stop" not in trials:
        return 0
    return int(trials["ended_at_stop"].fillna(False).astype(bool).sum())


def to_markdown(table: pd.DataFrame) -> str:
    def cell(v) -> str:
        if isinstance(v, float):
            return f"{v:g}" if not np.isnan(v) else "-"
        return str(v).replace("|", "\\|")

    head = "| " + " | ".join(cell(c) for c in table.columns) + " |"
    rule = "|" + "|".join("---" for _ in table.columns) + "|"
    rows = ["| " + " | ".join(cell(v) for v in row) + " |" for row in table.itertuples(index=False)]
    return "\n".join([head, rule, *rows])


def fell_before_takeover(frame: pd.DataFrame) -> pd.Series:
    """Trials whose seed phase fell before the evaluated phase began: the controller under test never acted,
    so they say nothing about it (their NWT is 0 for every controller) and are counted apart."""
    if "fall_time" not in frame or "eval_start" not in frame:
        return pd.Series(False, index=frame.index)
    start = frame["eval_start"].astype(float)
    return (frame["fall_time"].notna() & (start > 0) & (frame["fall_time"].astype(float) <= start + 1e-9)).astype(bool)
