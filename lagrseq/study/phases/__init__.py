"""``lagrseq reproduce`` in phases, each a function of its own module with typed inputs and outputs:

1. :func:`.plan.plan_suite` (:class:`.plan.Request` -> :class:`.plan.SuitePlan`): the distinct
   runs of the suite, the frontier's matched-rate random runs, the audits.
2. :func:`.estimate.estimate_suite` (-> :class:`.estimate.Forecast`): every distinct
   configuration timed on this machine (:mod:`.timing`, the estimator), the expected wall time said.
3. :func:`.execute.execute_suite` (-> :class:`.execute.Outcome`): the runs, the matched-rate
   random runs, the audits; a failed run does not stop the others (:mod:`.failures`).
4. :func:`.report.report_suite`: the error log, then replay into ``OUT/reports``.

:func:`lagrseq.study.reproduce.reproduce` calls them in turn with one
:class:`lagrseq.progress.Reporter`.
"""
