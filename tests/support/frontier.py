"""Frontier points made by hand, for the protocol's tests."""

from __future__ import annotations

import numpy as np
import pandas as pd

from lagrseq.analysis.frontier import Point
from lagrseq.analysis.loading import Run, RunKey


def point(policy: str, steps: list[float], queries: float = 10.0, decisions: float = 100.0, p: float | None = None,
          on_miss: str = "refuse", missed: float = 0.0) -> Point:
    """A frontier point made by hand: per-trial steps to the first solve, and the run's totals of
    queries, decisions and store misses (answers from ``on_miss``) spread over its trials."""
    secondary = {"policy": policy} if p is None else {"policy": policy, "ask_probability": p}
    method = {"always": "lagr", "never": "baseline"}.get(policy, "lagr-seq")
    config = {"method": method, "secondary": secondary, "lagr": {"solution_scope": "episode"}, "task": {"name": "cube-stacking"}}
    n = len(steps)
    run = Run(
        RunKey("cube-stacking", method, "paper", "recorded:store", 0, f"{policy}{p}"), config, (), tuple(range(n)),
        pd.DataFrame(), pd.DataFrame(), 0,
    )
    per_trial = np.full(n, queries / n)
    point = Point(
        policy, "" if p is None else f"p {p:g}", run, np.zeros(n), np.array(steps, dtype=float), np.ones(n, dtype=bool),
        per_trial, np.zeros(n), np.full(n, missed / n), decisions=decisions, on_miss=on_miss,
        episodes_solved=np.ones(n), outside=np.zeros(n, dtype=bool),
    )
    return point
