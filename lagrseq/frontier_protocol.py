"""The frontier protocol's shared definitions: what running the frontier
(:mod:`lagrseq.study.frontier`) and reporting it from the logs (:mod:`lagrseq.analysis.frontier`,
:mod:`lagrseq.analysis.items`) must agree on, kept below both so that analysis never imports study.

- :data:`TUNING_NOTE`: the run-metadata entry that marks a run ``--tune`` made;
- :func:`wants_match`: whether a policy's point is compared with random at its own query rate;
- :func:`matched_probability`: that rate, rounded so the report finds the same random run again.

Standard library and :mod:`lagrseq.registry` only.
"""

from __future__ import annotations

from lagrseq.registry import POLICIES

TUNING_NOTE = "frontier_tuning"
"""The run-metadata entry (JSON) of a run that ``--tune`` made: ``role`` ``tuning`` (a candidate or
the control on the tuning seeds) or ``tuned`` (the evaluation of the chosen setting)."""


def wants_match(policy: str, knobs: object) -> bool:
    """Whether a point is compared with random at its query rate, read from the policy's
    registry entry: every asking policy but the yardstick itself (random), one that peeks (the
    oracle), the baseline's (never), and a policy of plain LaGR without knobs (always: random at
    rate 1 is always). A policy this installation does not know (a plugin's, read back from
    its logs) is an asking policy like any other: matched."""
    spec = POLICIES.find(policy)
    if spec is None:
        return True
    if spec.peeks or spec.comparator or spec.method == "baseline":
        return False
    return spec.method != "lagr" or bool(knobs)


def matched_probability(queries: float, decisions: float) -> float:
    """The ``ask_probability`` of random at a run's mean query rate (queries / decisions over all
    its trials), to 2 significant digits and at least 0.001 (so the report finds the same run
    again from the logs)."""
    if decisions <= 0:
        raise ValueError("no decisions: the run never reached a trigger")
    rate = min(max(queries / decisions, 0.001), 1.0)
    return float(f"{rate:.2g}")
