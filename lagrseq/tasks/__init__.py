"""Pattern-completion tasks as data and pure functions (no other lagrseq layer imported).

- :mod:`lagrseq.tasks.cube`: cube stacking (5, 8 or 11 cubes).
- :mod:`lagrseq.tasks.grid`: what the grid tasks share (E, prompt, parser, pi_LLM, extrapolator).
- :mod:`lagrseq.tasks.image`, :mod:`lagrseq.tasks.arrangement`: image completion (10 x 10) and
  object arrangement (5 x 5) with their descriptors.
- :mod:`lagrseq.tasks.shapes`: the shape library (targets and extrapolator hypotheses).
"""
