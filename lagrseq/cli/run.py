"""``lagrseq run``, ``config`` and ``robot``: one experiment, its configuration, the arm's robot service."""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path
from typing import Any

from lagrseq.cli.options import (
    _COUNT,
    _N,
    _PORT,
    _SEED,
    _executor_options,
    _experiment_options,
    _make_executor,
    _provider_argument,
    _provider_flags,
    _provider_options,
    _quiet,
    _task_argument,
    takes_provider_flags,
)
from lagrseq.cli.output import _bar, _say, _shown


@takes_provider_flags("run")
def _add_run(sub: Any) -> None:
    from lagrseq.config import METHODS

    p = sub.add_parser(
        "run",
        parents=[_experiment_options(), _provider_flags(per="run"), _executor_options(), _quiet()],
        help="run trials of one task and method, logging every step to MCAP",
        description=(
            "Run TRIALS independent trials of one experiment and write one MCAP log per trial to "
            "OUT/<task>/<method>/<preset>-<provider>-seed<S>-<config digest>/trial-NNN.mcap. "
            "Trials whose log is complete are skipped, so an interrupted run can be resumed."
        ),
        epilog=(
            "examples:\n"
            "  lagrseq run cube-stacking --method lagr-seq --preset upstream --trials 10 --out runs\n"
            "  lagrseq run cube-stacking --method lagr --set env.horizon=100 --set llm.temperature=1.0\n"
            "  lagrseq run cube-stacking --method baseline --set task.stack_size=11\n"
            "  lagrseq run image-completion --method lagr-seq --preset paper --trials 2\n"
            "  lagrseq run cube-stacking --trials 32 --executor dask --jobs 4\n"
            "  lagrseq run cube-stacking --trials 256 --executor dask --scheduler tcp://head:8786\n"
            "  lagrseq run object-arrangement --method lagr --set task.target=\"square\"\n"
            "  lagrseq run arm-arrangement --preset paper --trials 5 --render frames   # the UR5e (arm extra)\n"
            "  lagrseq config cube-stacking --preset paper     # every field, its value and meaning\n\n"
            + _mock_profiles()
        ),
    )
    _task_argument(p)
    p.add_argument("--method", choices=METHODS, default="lagr-seq", metavar="METHOD", help="baseline (no LLM), lagr (asks when triggered), lagr-seq (default)")
    _provider_argument(p, "mock", "LLM provider (mock profiles: below)")
    p.add_argument("--trials", type=_COUNT, default=10, help="number of independent trials (default 10)")
    p.add_argument("--seed", type=_SEED, default=0, help="run seed below 2**63; trial k draws from (seed, k) (default 0)")
    p.add_argument("--out", type=Path, default=Path("runs"), help="output directory (default: runs)")
    p.add_argument("--name", default=None, help="run folder name (default: preset-provider-seed-digest)")
    p.add_argument("--jobs", type=_N["jobs"], default=1, help="parallel trial processes, or local Dask workers (default 1)")
    p.add_argument("--render", type=Path, default=None, metavar="DIR", help="arm-arrangement: frames and a GIF per episode in DIR (docs/arm.md)")


def _mock_profiles() -> str:
    """Every profile ``--provider mock:PROFILE`` accepts (``wiring.mock_profiles``), each with its
    meaning, wrapped to the terminal as argparse wraps the rest of the help."""
    import shutil
    import textwrap

    from lagrseq.running.wiring import REFUSING, REFUSING_HELP
    from lagrseq.tasks import grid_profiles
    from lagrseq.tasks.cube import PROFILE_HELP

    grids = {name: f"(image completion, object arrangement) {made.description}" for name, made in grid_profiles.PROFILES.items()}
    cubes = {name: (about if name == "ideal" else f"(cube stacking) {about}") for name, about in PROFILE_HELP.items()}
    width = max(shutil.get_terminal_size().columns - 2, 40)
    lines = ["mock profiles (--provider mock:PROFILE):"]
    for name, about in {**cubes, **grids, REFUSING: REFUSING_HELP}.items():
        lines += textwrap.wrap(f"{name}: {about}", width, initial_indent="  ", subsequent_indent="      ", break_on_hyphens=False)
    return "\n".join(lines)


def _add_robot(sub: Any) -> None:
    p = sub.add_parser(
        "robot",
        help="the robot service of arm-arrangement (gRPC): serve a simulated UR5e",
        description=(
            "Serve a robot over gRPC (lagrseq/robot/proto/robot.proto) for runs with "
            "--set env.robot=\"remote:HOST:PORT\". A lab with a real UR5e serves the same service "
            "with ur_rtde (see docs/arm.md, 'Robot service')."
        ),
        epilog="example:\n  lagrseq robot serve --sim --port 50051 &\n  lagrseq run arm-arrangement --set env.robot=\"remote:127.0.0.1:50051\"",
    )
    actions = p.add_subparsers(dest="robot_command", required=True, metavar="ACTION")
    serve = actions.add_parser("serve", help="serve a robot until interrupted (Ctrl-C)")
    serve.add_argument("--sim", action="store_true", required=True, help="serve a simulated UR5e (pybullet; the only robot lagrseq itself drives)")
    serve.add_argument("--host", default="127.0.0.1", help="listen address (default 127.0.0.1); any other needs --token-file and TLS")
    serve.add_argument("--port", type=_PORT, default=50051, help="TCP port (default 50051; 0 picks a free one and prints it)")
    serve.add_argument("--token-file", default=None, metavar="FILE", help="a shared secret file (one line, chmod 600); clients: env.robot_token_file")
    serve.add_argument("--tls-cert", default=None, metavar="FILE.pem", help="serve TLS with this certificate (clients: remote+tls:, env.robot_tls_ca)")
    serve.add_argument("--tls-key", default=None, metavar="FILE.pem", help="the private key of --tls-cert")
    serve.add_argument("--max-objects", type=_N["objects"], default=64, metavar="N", help="objects the table may hold; Place on a full table is refused (default 64)")


def _add_config(sub: Any) -> None:
    from lagrseq.config import METHODS

    p = sub.add_parser(
        "config",
        parents=[_experiment_options()],
        help="print the resolved configuration of an experiment, with each field's meaning",
        description="Print every field of the resolved configuration as TOML, with its docstring.",
    )
    _task_argument(p)
    p.add_argument("--method", choices=METHODS, default="lagr-seq")


def cmd_config(args: argparse.Namespace) -> int:
    from lagrseq import config as cfg
    from lagrseq.keys import scrub
    from lagrseq.text import shown

    resolved = cfg.load(args.task, args.method, args.preset, args.config, args.overrides)
    print(shown(f"# lagrseq {args.task}, method {args.method}, preset {args.preset}"))
    print("\n".join(shown(line) for line in scrub(_config_toml(resolved)).split("\n")))  # a key given as a value is never printed
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from lagrseq.cli.helpers import check_render
    from lagrseq.progress import Reporter, ignore
    from lagrseq.running import runner

    options = _provider_options(args)
    _make_executor(args, start=False)  # --executor/--scheduler checked before anything is made
    check_render(args.task, args.render)
    config, directory = runner.prepare(
        args.task, args.method, args.preset, args.config, args.overrides,
        args.provider, options, args.out, args.seed, args.name,
    )
    unit, per_trial = runner.progress_unit(config)
    with contextlib.ExitStack() as stack:
        pending = runner.resume_plan(config, args.trials, args.seed, args.provider, directory, options).todo
        pool = _make_executor(args, start=bool(pending))  # no cluster to start for nothing
        if pool is not None:
            stack.enter_context(pool)
        # --quiet: no bar at all (tqdm, never drawn, would cost about 10% of a short run's start-up)
        quiet: contextlib.AbstractContextManager[Any] = contextlib.nullcontext(None)
        with quiet if args.quiet else _bar(args.trials * per_trial, unit, f"{args.task} {args.method}", False) as bar:
            results = runner.run_trials(
                config, args.trials, args.seed, args.provider, directory, args.jobs, bar, options,
                pool=pool, retries=args.retries, render_dir=args.render,
                # a failed trial is named at once above the bar; --quiet: only in the closing line
                reporter=Reporter(_say, ignore if args.quiet else (lambda line: bar.write(f"lagrseq run: warning: {_shown(line)}", file=sys.stderr))),
            )
    print(runner.summary(results, directory, args.provider))
    return 0


def cmd_robot(args: argparse.Namespace) -> int:
    from lagrseq.progress import Reporter
    from lagrseq.robot.remote import check_listen, security_for, serve_sim

    check_listen(args.host, args.port)  # an address this machine cannot listen on is said first
    security = security_for(args.host, args.token_file, args.tls_cert, args.tls_key, args.max_objects)
    serve_sim(args.host, args.port, Reporter(_say), security=security)
    return 0


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


def _config_toml(resolved: Any) -> str:
    """Every field of a resolved configuration as TOML, each with its docstring."""
    import dataclasses

    from lagrseq import config as cfg

    lines = [f'method = "{resolved.method}"']
    for section in dataclasses.fields(resolved):
        value = getattr(resolved, section.name)
        if not dataclasses.is_dataclass(value):
            continue
        docs = cfg.section_docs(value)
        lines.append(f"\n[{section.name}]")
        for f in dataclasses.fields(value):
            doc = docs.get(f.name, "")
            if f.name == "knobs":  # the policy's own knobs: NAME = VALUE, as they are written, unset ones at their default
                lines += [f"{k.name} = {_toml_value(k.value)}  # {k.help}" for k in cfg.knob_lines(value)]
                continue
            lines.append(f"{f.name} = {_toml_value(getattr(value, f.name))}" + (f"  # {doc}" if doc else ""))
    return "\n".join(lines)
