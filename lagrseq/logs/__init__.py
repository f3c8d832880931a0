"""MCAP logs: topic schemas, the sink that writes a trial, the reader.

Topics the readers give (public contract): ``/transition``, ``/query``, ``/episode``; run
configuration and seed in the ``lagrseq.run`` metadata record, completion status in
``lagrseq.status``. Log formats 3 and 4 store an episode's transitions and its decisions not to ask as
one columnar record each (``/transitions``, ``/no_query``; :mod:`lagrseq.logs.columns` expands
them), formats 1 and 2 one record per step and decision.
"""
