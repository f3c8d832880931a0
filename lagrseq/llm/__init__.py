"""LLM providers: text in, text and usage out. They know nothing of RL, tasks or logs.

- :mod:`lagrseq.llm.base`: ``Query``, ``Answer``, ``Usage`` and the ``Provider`` interface.
- :mod:`lagrseq.llm.mock`: the rule-based mock provider (the embedded default).
"""
