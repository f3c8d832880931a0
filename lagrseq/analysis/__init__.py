"""Offline analysis: MCAP logs -> pandas -> the paper's figures, tables and costs.

- :mod:`~lagrseq.analysis.loading`: logs grouped into runs (task, method, preset, provider, seed,
  configuration digest), as pandas frames of episodes and queries.
- :mod:`~lagrseq.analysis.stats`: mean, standard deviation, standard error, seeded bootstrap
  confidence intervals, Student-t summaries, curves over trials (every trial at every point).
- :mod:`~lagrseq.analysis.inference`: t and Welch intervals (scipy.stats), estimates with their
  standard errors (lagrseq's and a paper's), log-scale intervals of counts and ratios, contrasts
  and slopes, three-way equivalence verdicts (TOST, two-sample against a paper value), trends,
  non-inferiority, Holm.
- :mod:`~lagrseq.analysis.margins`: the scoreboard's margins per quantity (scale, margin, why) and
  the paper's sample sizes, in one table.
- :mod:`~lagrseq.analysis.provenance`: what made a run's numbers (authors' answers, open model,
  fitted, rule-based mock, no LLM), from its logged provider and configuration; which trials a
  fallback decided (their first accepted answer not from the store).
- :mod:`~lagrseq.analysis.scoreboard`: the paper's numbers beside lagrseq's, with provenance and
  verdicts (docs/verdicts.md).
- :mod:`~lagrseq.analysis.figures`: plot functions; each takes ``ax=None`` and returns it, never
  saves.
- :mod:`~lagrseq.analysis.tables`: tables as Markdown, CSV and HTML text.
- :mod:`~lagrseq.analysis.costs`: queries, tokens and USD per run and per method (``/query`` only).
- :mod:`~lagrseq.analysis.items`: one builder per kind of paper item (data, figure, tables).
- :mod:`~lagrseq.analysis.replay`: the only module that writes files.

This package imports no environment, agent, LLM provider, torch, gymnasium, httpx or pybullet:
``lagrseq replay`` runs with the core dependencies alone.
"""
