"""Key guard benchmark: what blanking the key costs (issue 37 item 1).

    PYTHONPATH=. python benchmarks/bench_key_guard.py
    PYTHONPATH=. python benchmarks/bench_key_guard.py --repeats 9 --mib 4

1. :meth:`lagrseq.keys.Redactor.text` on bodies of ``--mib`` MiB (a 164-character key, as
   OpenAI's): ordinary ASCII answers, answers with a space between every word (the invisible
   characters are removed before matching), CJK text whose every character is distinct (one
   Unicode lookup per distinct character), the key with a zero-width space every 4 characters
   (everything is a match), and zero-width spaces alone. Median and range of ``--repeats`` runs,
   in milliseconds and MiB/s.
2. ``lagrseq run cube-stacking`` (mock provider, 1 trial of 20 episodes) with and without a key
   in ``OPENAI_API_KEY`` (so every /query record and the metadata go through the guard): median
   and range of ``--repeats`` runs each, in seconds, alternated so that drift hits both.
"""

from __future__ import annotations

import argparse
import os
import statistics
import string
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lagrseq.keys import Redactor

ROOT = Path(__file__).resolve().parents[1]


def bodies(key: str, size: int) -> dict[str, str]:
    words = "the cube goes on top of the stack [4, 5, 6, 7] and then "
    cjk = "".join(chr(c) for c in range(0x4E00, 0x4E00 + 20_000))
    spaced = "\u200b".join(key[i : i + 4] for i in range(0, len(key), 4)) + " "
    return {
        "ordinary ASCII answer": (words * (size // len(words) + 1))[:size],
        "ASCII, no whitespace": ("[4,5,6,7];" * (size // 10 + 1))[:size],
        "CJK, 20,000 distinct characters": (cjk * (size // len(cjk) + 1))[: size // 3],
        "the key, zero-width space every 4": (spaced * (size // len(spaced) + 1))[: size // 3],
        "zero-width spaces alone": "\u200b" * (size // 3),
    }


def spread(values: list[float]) -> str:
    return f"median {statistics.median(values):.1f} (range {min(values):.1f} to {max(values):.1f}, n = {len(values)})"


def redactor_figures(repeats: int, mib: float) -> None:
    key = "sk-proj-" + "".join(np.random.default_rng(0).choice(list(string.ascii_letters + string.digits), 156))
    redactor = Redactor(key)
    size = int(mib * 1024 * 1024)
    print(f"Redactor.text, key of {len(key)} characters, bodies of about {mib:g} MiB (CJK and zero-width bodies: a third as many characters)")
    for name, text in bodies(key, size).items():
        redactor.text(text[:1000])  # warm
        times = []
        for _ in range(repeats):
            started = time.perf_counter()
            redactor.text(text)
            times.append((time.perf_counter() - started) * 1000)
        megabytes = len(text.encode("utf-8")) / 1024 / 1024
        print(f"  {name:<36} {len(text):>9,} chars  {spread(times)} ms  ({megabytes / (statistics.median(times) / 1000):.0f} MiB/s)")


def run_figures(repeats: int) -> None:
    print("lagrseq run cube-stacking --trials 1 --set run.episodes=20 (mock), seconds per run")
    timings: dict[str, list[float]] = {"no key in the environment": [], "a key in OPENAI_API_KEY": []}
    for _ in range(repeats):
        for name in timings:
            env = {k: v for k, v in os.environ.items() if k != "OPENAI_API_KEY"}
            if name.startswith("a key"):
                env["OPENAI_API_KEY"] = "sk-proj-" + "x1Y2" * 40
            env["PYTHONPATH"] = str(ROOT)
            with tempfile.TemporaryDirectory() as out:
                started = time.perf_counter()
                subprocess.run([sys.executable, "-m", "lagrseq", "run", "cube-stacking", "--trials", "1", "--set", "run.episodes=20",
                                "--out", out, "--quiet"], check=True, capture_output=True, env=env, cwd=ROOT)
                timings[name].append(time.perf_counter() - started)
    for name, values in timings.items():
        print(f"  {name:<28} {spread(values)} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--mib", type=float, default=4.0)
    args = parser.parse_args()
    redactor_figures(args.repeats, args.mib)
    run_figures(args.repeats)


if __name__ == "__main__":
    main()
