"""Pattern-completion tasks as data and pure functions (no other lagrseq layer imported).

- :mod:`lagrseq.tasks.cube`: cube stacking (5, 8 or 11 cubes).
"""
