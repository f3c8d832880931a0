"""lagrseq: an offline-first reproducibility toolkit for LaGR-SEQ.

LaGR-SEQ (Language-Guided Reinforcement Learning with Sample-Efficient Querying): a primary RL
agent solves a pattern-completion task; after a positive reward an LLM may extrapolate the full
pattern from the partial one (LaGR); a secondary agent learns when such a query is worth it (SEQ).
"""

__version__ = "0.1.0"
