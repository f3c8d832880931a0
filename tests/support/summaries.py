"""Per-trial values summarized with a percentile bootstrap interval (the package's tables use
Student's t: :func:`lagrseq.analysis.stats.summarize_t`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lagrseq.analysis.stats import CONFIDENCE, Interval, bootstrap_ci, mean_std_se


def summarize(values: Sequence[float] | np.ndarray, rng: np.random.Generator) -> Interval:
    """Mean, spread and a bootstrap interval of per-trial values."""
    x = np.asarray(values, dtype=float)
    mean, std, se = mean_std_se(x)
    low, high = bootstrap_ci(x, rng)
    return Interval(int(x.size), mean, low, high, CONFIDENCE, std, se)
