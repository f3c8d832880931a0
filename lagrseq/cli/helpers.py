"""What the command line's commands need beyond parsing: the ``--render`` check, the model a
``record`` asks, ``lagrseq models``' listing, ``lagrseq serve-llm``, and the price function of
replay's and the frontier's cost tables. Each imports what it runs inside its body, so the
command line starts without the loop or wiring."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lagrseq.errors import LagrseqError, UsageError
from lagrseq.registry import PROVIDERS, TASKS

if TYPE_CHECKING:
    from lagrseq.progress import Reporter


def price_function(price_table: str | None) -> Callable[[str, int, int], float | None]:
    """``(model, prompt tokens, completion tokens) -> USD or None`` from the dated price table
    (``price_table`` over the built-in one), for replay's and the frontier's cost tables."""
    from lagrseq.llm.base import Usage
    from lagrseq.running.wiring import load_prices

    table = load_prices(price_table)
    return lambda model, prompt, completion: table.cost(Usage(prompt, completion), model)  # type: ignore[no-any-return]


def model_of(provider: str, model: str | None) -> str | None:
    """The model ``lagrseq record --provider`` asks: ``--model``, else the one the spec names (a
    local model by its own name); None: the configuration's."""
    if model is not None:
        return model
    from lagrseq.running.wiring import parse_provider

    spec = parse_provider(provider)
    kind = PROVIDERS.get(spec.kind)
    if kind.local_server:
        from lagrseq.llm.local import model_name

        return model_name(spec.argument)
    return None


def check_render(task: str, render: Path | None) -> None:
    """``--render DIR``: the task must draw its episodes, and DIR must be writable."""
    if render is None:
        return
    from lagrseq.paths import writable_directory

    if not TASKS.get(task).renders:
        drawn = ", ".join(spec.name for spec in TASKS.specs() if spec.renders)
        raise UsageError(f"--render draws the arm of {drawn} only, not {task}; leave it out")
    writable_directory(render, "--render")


def model_listing(paths: list[Path], hash_files: bool, as_json: bool) -> tuple[list[str], list[str]]:
    """``lagrseq models``: the lines describing every GGUF model found (text blocks, or one JSON
    object a line), and the problems of the paths given that are not GGUF files."""
    import json

    from lagrseq.llm.gguf import find_models, model_lines

    models = find_models(paths, hash_files=hash_files)
    given_bad = [model for model in models if model.problem and model.found_by == "path"]
    found = [model for model in models if model not in given_bad]
    # JSON with ASCII escapes: a file name that is not UTF-8 (lone surrogates) stays valid JSON
    lines = [json.dumps(model.row()) for model in found] if as_json else model_lines(found)
    return lines, [f"{model.path}: {model.problem}" for model in given_bad]


def serve_llm(model: str, port: int, n_ctx: int, threads: int, log: Any, reporter: Reporter) -> None:
    """``lagrseq serve-llm``: a llama.cpp server until interrupted (SIGTERM stops it as Ctrl-C
    does: the command line's handler); its address line is said to ``reporter``, the server's own
    lines (starting, ready, stopped) are its warnings (stderr)."""
    import time

    from lagrseq.llm.local import LocalServer
    from lagrseq.llm.options import LocalOptions
    from lagrseq.running.wiring import local_settings

    settings = local_settings(model, LocalOptions(n_ctx=n_ctx, threads=threads), port=port)

    with LocalServer(settings, log=log, reporter=reporter) as server:
        reporter.say(f"{server.base_url}  model {settings.model_name}  (use: --provider live:{settings.model_name} --base-url {server.base_url} --server llama.cpp; Ctrl-C stops it)")
        while server.running:
            time.sleep(0.5)
        lines = server.log_tail().strip().splitlines()
        raise LagrseqError(f"the llama.cpp server exited by itself: {lines[-1] if lines else 'no output'}")
