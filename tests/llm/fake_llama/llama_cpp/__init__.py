"""Stand-in for llama-cpp-python in tests: only ``python -m llama_cpp.server`` (see server/__main__.py)."""
