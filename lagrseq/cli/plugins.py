"""``lagrseq plugins`` and ``info``: what is installed."""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

from lagrseq.cli.options import drop_clashing_plugin_flags


def _add_plugins(sub: Any) -> None:
    p = sub.add_parser(
        "plugins",
        help="list the tasks, providers, asking policies and executors, built-in and from plugins",
        description=(
            "List every registered task, provider kind, asking policy and executor with the "
            "distribution it comes from (lagrseq: built in). Plugins register through the "
            "entry-point groups lagrseq.tasks, lagrseq.providers, lagrseq.policies, lagrseq.executors; "
            "one that fails to load is listed as skipped (docs/extending.md). With --check: each part "
            "of every installed plugin loads, its names, knobs and flags collide with nothing, each task "
            "passes Gymnasium's env checker and a short run logs the fields it declares."
        ),
    )
    p.add_argument("--check", action="store_true", help="check every installed plugin instead (exit 2: one line a problem)")


def _add_info(sub: Any) -> None:
    sub.add_parser(
        "info",
        help="what to paste into a bug report: version, Python, extras, torch's device, output folders",
        description=(
            "Print lagrseq's version, the Python it runs on, every extra with the installed "
            "version of each of its packages, the device torch would use (without importing any "
            "other extra) and where each command writes by default."
        ),
    )


def cmd_plugins(args: argparse.Namespace) -> int:
    from lagrseq import registry

    if args.check:  # each problem once, below: the loading's own skip lines are not printed
        os.environ[registry.NOTICES_ENV] = "0"
    drop_clashing_plugin_flags()
    if not args.check:
        print("\n".join(registry.listing()))
        return 0
    from lagrseq.progress import Reporter
    from lagrseq.study.plugin_check import check

    problems = check(Reporter())
    for problem in problems:
        print(f"lagrseq plugins --check: {problem}", file=sys.stderr)
    print(f"{len(problems)} problem{'' if len(problems) == 1 else 's'} found")
    return 2 if problems else 0


def cmd_info(args: argparse.Namespace) -> int:
    from lagrseq.info import lines

    for line in lines():
        print(line)
    return 0
