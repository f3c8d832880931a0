"""Stand-in so that lagrseq finds the local-llm extra (tests only)."""
