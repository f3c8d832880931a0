"""LLM providers: text in, text and usage out. They know nothing of RL, tasks or logs.

- :mod:`lagrseq.llm.base`: ``Query``, ``Answer``, ``Usage`` and the ``Provider`` interface.
- :mod:`lagrseq.llm.mock`: the rule-based mock provider (the embedded default).
- :mod:`lagrseq.llm.live`: OpenAI-compatible Chat Completions over httpx (retries, timeouts, ``n``,
  a deadline and a size cap per request, token counts believed only up to what a request can use).
- :mod:`lagrseq.llm.store`: the recorded multi-sample store (JSON-only diskcache) and its JSONL form.
- :mod:`lagrseq.llm.recorded`: replaying a store, and the recording wrapper (vcrpy modes).
- :mod:`lagrseq.llm.budget`: stop before a request that could pass a cost or query limit.
- :mod:`lagrseq.llm.pricing`: the dated price table; cost from usage.
- :mod:`lagrseq.llm.authors_cache`: the paper's authors' pickles, read with a numpy-only unpickler.
- :mod:`lagrseq.llm.servers`: kinds of OpenAI-compatible servers (stdlib only).

Task knowledge comes in from outside as plain functions: the mock's handler (a task's
extrapolator, or a calibrated profile of it) and the importer's ``prompt_for(key)``.
"""
