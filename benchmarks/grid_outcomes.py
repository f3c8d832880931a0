"""Steps to the goal and queries per trial, from the MCAP logs of grid runs (``/episode`` only).

    for t in image-completion object-arrangement; do for p in paper upstream; do
      for m in baseline lagr lagr-seq; do
        PYTHONPATH=. python -m lagrseq run $t --method $m --preset $p --provider mock \\
            --trials 2 --seed 0 --out /tmp/grid-runs --quiet
      done; done; done
    PYTHONPATH=. python benchmarks/grid_outcomes.py /tmp/grid-runs

"first goal" is the trial step at which the first episode that reached the goal ended (the goal:
E >= task.goal_threshold; the episode ends there under ``goal_ends="episode"``, at the end of its
last scan under the released scan rule); "-" if no episode did within the budget.
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np

from lagrseq.logs.reader import find_logs, read_info, read_topic


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", help="run directories or MCAP files")
    args = parser.parse_args(argv)
    rows: dict[tuple[str, str, str], list[dict]] = defaultdict(list)
    for path in find_logs(args.runs):
        info = read_info(path)
        episodes = read_topic(path, "/episode")
        first = next((e["global_step"] for e in episodes if e["solved"]), None)
        rows[info.config["task"]["name"], info.run["preset"], info.config["method"]].append(
            {
                "trial": int(info.run["trial"]),
                "seed": info.run["seed"],
                "first_goal": first,
                "queries": sum(e["queries"] for e in episodes),
                "return": sum(e["return"] for e in episodes),
                "solved": float(np.mean([e["solved"] for e in episodes])),
                "steps": episodes[-1]["global_step"] if episodes else 0,
            }
        )
    print(f"{'task':<19} {'preset':<9} {'method':<9} {'first goal (per trial)':<24} {'queries':<16} "
          f"{'return':>7} {'solved':>7}")  # fmt: skip
    for (task, preset, method), trials in sorted(rows.items()):
        trials.sort(key=lambda r: (r["seed"], r["trial"]))
        firsts = ", ".join("-" if r["first_goal"] is None else str(r["first_goal"]) for r in trials)
        queries = np.array([r["queries"] for r in trials], dtype=float)
        se = queries.std(ddof=1) / np.sqrt(len(queries)) if len(queries) > 1 else 0.0
        print(
            f"{task:<19} {preset:<9} {method:<9} {firsts:<24} {queries.mean():>6.1f} +- {se:<6.2f} "
            f"{np.mean([r['return'] for r in trials]):>7.1f} {np.mean([r['solved'] for r in trials]):>7.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
