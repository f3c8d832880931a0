"""Recording benchmark: `lagrseq record --concurrency N` against a server with a fixed latency, and
the local open LLM's answers and tokens per second.

    PYTHONPATH=. python benchmarks/bench_record.py                  # fixed-latency server only
    PYTHONPATH=. python benchmarks/bench_record.py --local          # and the local LLM (local-llm extra)
    PYTHONPATH=. python benchmarks/bench_record.py --local --local-samples 2 --local-concurrency 1,2

1. A Chat Completions server on 127.0.0.1 that answers every request after exactly ``--latency``
   seconds (200 ms) records the same 8 cube prefixes x K samples (one request per sample, as for
   llama.cpp) with N = 1, 4, 16 requests in flight; it prints answers per second and the speedup
   over N = 1, against the target of at least 0.8 N.
2. With ``--local``: lagrseq starts the llama.cpp server with the packaged SmolLM2-135M-Instruct
   and records the 8 prefixes at tau = 1; it prints answers per second and completion tokens per
   second (the tokens the server reports) for each concurrency given.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from lagrseq import config as cfg
from lagrseq.llm.store import RecordStore
from lagrseq.running import recording
from lagrseq.running.wiring import LocalOptions, provider_options

TARGET = 0.8


class FixedLatencyServer:
    """Answers every POST after ``latency`` seconds with a one-choice chat completion."""

    def __init__(self, latency: float) -> None:
        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args: Any) -> None:
                return None

            def do_POST(self) -> None:
                body = json.loads(self.rfile.read(int(self.headers.get("Content-Length", "0"))))
                time.sleep(latency)
                data = json.dumps({
                    "id": "chatcmpl-bench", "object": "chat.completion", "model": body["model"],
                    "choices": [{"index": 0, "message": {"role": "assistant", "content": "['a','b','c','d','e','f','g','h']"}, "finish_reason": "stop"}],
                    "usage": {"prompt_tokens": 100, "completion_tokens": 20, "total_tokens": 120},
                }).encode()
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


def queries(model: str, temperature: float) -> list[Any]:
    config = recording.record_config("cube-stacking", "upstream", None, [], model, temperature)
    return recording.queries_for(config, recording.record_patterns(config))


def timed_record(store: Path, options: Any, samples: int, concurrency: int, provider: str, model: str, temperature: float) -> tuple[float, int, int]:
    """(seconds, answers, completion tokens) of recording the 8 prefixes x ``samples``."""
    started = time.perf_counter()
    report = recording.record(queries(model, temperature), store, samples, "new", options, None, provider, concurrency)
    seconds = time.perf_counter() - started
    with RecordStore(store, create=False) as opened:
        tokens = sum(s.usage.completion_tokens for e in opened.entries() for s in e.samples if s.usage is not None)
    return seconds, report.answers, tokens


def fixed_latency(latency: float, samples: int, levels: list[int]) -> None:
    server = FixedLatencyServer(latency)
    options = provider_options("live", {"base_url": server.url, "server": "ollama"})
    print(f"fixed-latency server ({latency * 1000:.0f} ms a request), 8 prefixes x {samples} samples = {8 * samples} requests")
    base = None
    try:
        for n in levels:
            with tempfile.TemporaryDirectory(prefix="lagrseq-bench-") as scratch:
                seconds, answers, _ = timed_record(Path(scratch) / "s", options, samples, n, "live", "gpt-4o-mini", 1.0)
            rate = answers / seconds
            base = base or rate
            speedup = rate / base
            verdict = "ok" if speedup >= TARGET * n else f"below the target {TARGET * n:.1f}"
            print(f"  N = {n:2d}: {answers} answers in {seconds:6.2f} s = {rate:6.1f} answers/s, speedup {speedup:5.2f} x ({verdict})")
    finally:
        server.close()


def local(samples: int, levels: list[int], threads: int) -> None:
    from lagrseq.llm.local import DEFAULT_MODEL_NAME, missing_extra

    problem = missing_extra()
    if problem:
        print(f"local LLM: skipped: {problem}")
        return
    options = LocalOptions(threads=threads)
    print(f"local LLM {DEFAULT_MODEL_NAME} (llama.cpp, {threads or os.cpu_count()} threads), 8 prefixes x {samples} samples at tau = 1 (server start included)")
    for n in levels:
        with tempfile.TemporaryDirectory(prefix="lagrseq-bench-") as scratch:
            seconds, answers, tokens = timed_record(Path(scratch) / "s", options, samples, n, "local", DEFAULT_MODEL_NAME, 1.0)
        print(f"  N = {n}: {answers} answers in {seconds:6.1f} s = {answers / seconds:5.2f} answers/s, {tokens / seconds:6.1f} completion tokens/s ({tokens} tokens)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--latency", type=float, default=0.2, help="seconds per request of the fixed-latency server (default 0.2)")
    parser.add_argument("--samples", type=int, default=16, help="samples per prefix against it (default 16: 128 requests)")
    parser.add_argument("--levels", default="1,4,16", help="concurrency levels (default 1,4,16)")
    parser.add_argument("--local", action="store_true", help="also measure the local LLM (needs the local-llm extra)")
    parser.add_argument("--local-samples", type=int, default=2, help="samples per prefix for the local LLM (default 2)")
    parser.add_argument("--local-concurrency", default="1", help="concurrency levels for the local LLM (default 1)")
    parser.add_argument("--threads", type=int, default=0, help="llama.cpp threads (default 0: every core)")
    args = parser.parse_args()
    os.environ.pop("OPENAI_API_KEY", None)  # nothing here talks to OpenAI
    cfg.load("cube-stacking", "lagr", "upstream")  # fail early on a broken install
    import httpx  # noqa: F401  (imported once here, not inside the first timing)

    import lagrseq.llm.concurrent  # noqa: F401
    import lagrseq.llm.live  # noqa: F401
    fixed_latency(args.latency, args.samples, [int(x) for x in args.levels.split(",")])
    if args.local:
        local(args.local_samples, [int(x) for x in args.local_concurrency.split(",")], args.threads)


if __name__ == "__main__":
    main()
