"""MCAP logs: topic schemas, the sink that writes a trial, the reader.

Topics (public contract): ``/transition``, ``/query``, ``/episode``; run configuration and seed in
the ``lagrseq.run`` metadata record, completion status in ``lagrseq.status``.
"""
