"""``lagrseq audit TASK``: run every one-field switch between the ``upstream`` and ``paper`` presets
and report what each deviation does (the numbers come from :mod:`lagrseq.analysis.audit`, which
rebuilds them from the logs alone; ``lagrseq replay`` does the same for any logs holding such runs).

Runs: both presets as they are, then for every audited field the upstream preset with that field
set to the paper's value and the paper preset with it set back, each for the baseline, LaGR and
LaGR-SEQ (a method whose trials cannot read the field, e.g. the baseline for ``lagr.*``, keeps
the preset's run). Then, where the task names interaction fields
(:data:`lagrseq.analysis.audit.INTERACTIONS`), every combination of two or more of them switched
together on the upstream preset (again only for the methods that read at least two of them; the
others' corners are runs already made). The baseline always uses the plain mock provider (it never
asks).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lagrseq import config as cfg
from lagrseq import outputs
from lagrseq.config import ExperimentConfig
from lagrseq.errors import ConfigError, UsageError
from lagrseq.logs.reader import is_complete
from lagrseq.progress import Reporter
from lagrseq.running import runner, wiring
from lagrseq.text import shown


@dataclass(frozen=True)
class AuditRun:
    preset: str
    field: str | None
    method: str
    config: ExperimentConfig
    provider: str
    path: Path


def plan(
    task: str,
    provider: str,
    trials: int,
    episodes: int,
    max_steps: int,
    runs_dir: Path,
    seed: int,
    reporter: Reporter,
    presets: tuple[str, ...] | None = None,
) -> list[AuditRun]:
    """The audit's runs; ``presets`` limits the one-field switches to those presets' directions
    (default both; both presets' own runs are always planned)."""
    from lagrseq.analysis.audit import (
        INTERACTION_PRESET,
        METHODS,
        PRESETS,
        audited_fields,
        interaction_sets,
        override,
        relevant,
        relevant_part,
        switched_value,
    )

    missing = [p for p in PRESETS if p not in cfg.task_presets(task)]
    if missing:
        raise UsageError(
            f"lagrseq audit switches fields between the {' and '.join(PRESETS)} presets; task {task!r} ships no "
            f"{missing[0]!r} preset (it has: {', '.join(cfg.task_presets(task))}); audit a task that ships both"
        )
    length = ([f"run.episodes={episodes}"] if episodes > 0 else []) + ([f"run.max_steps={max_steps}"] if max_steps >= 0 else [])
    fields = audited_fields(task)
    out: list[AuditRun] = []
    directions = PRESETS if presets is None else presets
    for preset in PRESETS:
        for field in [None, *(name for name, _, _ in fields if preset in directions)]:
            for method in METHODS:
                if field is not None and not relevant(field, method):
                    continue
                sets = list(length)
                if field is not None:
                    sets.append(override(field, switched_value(field, preset, fields)))
                try:
                    config = cfg.load(task, method, preset, None, sets)
                except ConfigError as exc:
                    reporter.say(f"{preset} + {field}: cannot be switched alone ({exc}); left out")
                    break
                spec = "mock" if method == "baseline" else provider
                path = runner.run_directory(runs_dir, config, spec, seed)
                out.append(AuditRun(preset, field, method, config, spec, path))
    for together in interaction_sets(task, fields):
        for method in METHODS:
            if relevant_part(together, method) != together:
                continue  # its corner is the run of the part it reads, planned already
            sets = list(length) + [override(f, switched_value(f, INTERACTION_PRESET, fields)) for f in sorted(together)]
            try:
                config = cfg.load(task, method, INTERACTION_PRESET, None, sets)
            except ConfigError as exc:
                reporter.say(f"{INTERACTION_PRESET} + {' + '.join(sorted(together))}: cannot be switched together ({exc}); left out")
                continue
            spec = "mock" if method == "baseline" else provider
            path = runner.run_directory(runs_dir, config, spec, seed)
            out.append(AuditRun(INTERACTION_PRESET, " + ".join(sorted(together)), method, config, spec, path))
    return out


def run_audit(
    task: str,
    provider: str,
    trials: int,
    episodes: int,
    max_steps: int,
    out: Path,
    jobs: int,
    seed: int,
    formats: list[str],
    reporter: Reporter | None = None,
) -> list[Any]:
    """Run the audit of ``task`` into ``OUT/runs`` and write ``OUT/reports/audit-TASK.*``;
    returns the audits built from the logs. ``reporter`` (default: lines on stdout, warnings on
    stderr, :func:`warn_on_stderr`) says the plan and each log left out, and shows the bar unless
    quiet."""
    from lagrseq.paths import writable_directory
    from lagrseq.progress import bar as progress_bar

    wiring.parse_provider(provider)
    writable_directory(out)
    runs_dir, reports = writable_directory(out / "runs"), writable_directory(out / "reports", "--out")
    reporter = reporter or Reporter(warn=warn_on_stderr)
    runs = plan(task, provider, trials, episodes, max_steps, runs_dir, seed, reporter)
    pending = sum(not is_complete(runner.trial_path(r.path, t)) for r in runs for t in range(trials))
    fields = len({r.field for r in runs if r.field and " + " not in r.field})
    together = len([r for r in runs if r.field and " + " in r.field])
    reporter.say(
        f"audit of {task}: {fields} fields x 2 presets"
        + (f" and {together} interaction runs (fields switched together)" if together else "")
        + f", {len(runs)} runs of {trials} trials ({pending} trials to run)"
    )
    with progress_bar(len(runs) * trials, "trial", quiet=reporter.quiet) as bar:
        sweep = [runner.SweepRun(r.config, trials, seed, r.provider, r.path, progress=runner.TrialCount(bar, r.config)) for r in runs]
        runner.run_sweep(sweep, jobs)  # every run's trials in one pool: no worker waits on a run's last trial
    return write_audit([runs_dir], reports, formats, task, reporter)


def warn_on_stderr(line: str) -> None:
    """``lagrseq audit``'s warning: one line on stderr."""
    print(f"lagrseq audit: warning: {shown(line)}", file=sys.stderr)


def write_audit(
    roots: list[Path], reports: Path, formats: list[str], task: str | None = None, reporter: Reporter | None = None
) -> list[Any]:
    """Build the audits from the logs under ``roots`` and write table (Markdown, CSV) and figure;
    ``reporter`` is warned about each log left out (damaged, unfinished: one line naming its full
    path)."""
    from lagrseq.analysis import audit, loading
    from lagrseq.analysis.tables import to_csv, to_markdown

    logs = loading.load(roots)
    for warning in logs.warnings:
        if reporter is not None:
            reporter.warn(warning)
    made = [a for a in audit.build(logs.runs) if task is None or a.task == task]
    for a in made:
        for stem, table, fig in audit.outputs(a):
            path = reports / stem
            outputs.write_text(path.with_suffix(".md"), to_markdown(table), "--out")
            outputs.write_text(path.with_suffix(".csv"), to_csv(table.data), "--out")
            for fmt in formats:
                outputs.save_figure(fig, path.with_suffix(f".{fmt}"), "--out", format=fmt, dpi=150, metadata={"Software": None} if fmt == "png" else None)
    return made
