"""``lagrseq screen``: how often an open model is right on a task's prompts, before anyone records
it for a whole suite.

A screen asks a model (``--provider local:MODEL`` or ``live``) N of the task's prompts, spread
evenly over the prefix lengths of the cube target (cube stacking) or over the fill fractions of
the states met in earlier runs (grid tasks, ``--from-runs``), keeps every answer as recorded-answer
JSONL (the ``recorded_llm/`` format), and reads the answers through the task's parser: accuracy
per prefix length or fill fraction with n and a Wilson 95% interval, the kinds of refusal, the
seconds per answer and tokens per second, answers cut at the token limit. The table (Markdown
and CSV) and a Fig. 4-style picture are rebuilt from the JSONL alone (``lagrseq screen --from
FILE.jsonl``), so neither the ``local-llm`` extra nor a model file is needed to reproduce them.

"Right" is the task's own acceptance: the exact target (cube stacking: the whole stack; grid
tasks: every cell), what an answer must be for LaGR's threshold of 1.0 on these tasks.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lagrseq.config import ExperimentConfig
from lagrseq.errors import UsageError

Z95 = 1.959963984540054
"""The normal quantile of a two-sided 95% interval."""
MAX_PROMPTS = 10_000
MAX_ANSWER_FILES = 64


def wilson(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of ``successes`` out of ``n`` (``(0, 1)`` for n = 0)."""
    if n <= 0:
        return 0.0, 1.0
    if not 0 <= successes <= n:
        raise ValueError(f"{successes} successes out of {n}")
    p = successes / n
    denominator = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denominator
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denominator
    # at k = 0 or k = n the bound is exactly 0 or 1 (rounding would put it a hair inside)
    return (0.0 if successes == 0 else max(0.0, centre - half)), (1.0 if successes == n else min(1.0, centre + half))


# ------------------------------------------------------------------------------------------
# Which prompts: spread evenly over prefix lengths or fill fractions
# ------------------------------------------------------------------------------------------
def bin_of(task: Any, pattern: Any) -> int:
    """The cell a pattern falls in: cube stacking, the prefix length (cubes shown); grid tasks,
    the cells of the target already on (how much of the pattern is shown)."""
    from lagrseq.tasks import cube

    if isinstance(task, cube.CubeStacking):
        return len(pattern)
    grid = np.asarray(pattern)
    return int(np.count_nonzero((grid != 0) & (task.target != 0)))


def bin_of_prompt(task: Any, prompt: str) -> int | None:
    """:func:`bin_of` the pattern a prompt shows (None: the prompt shows none of this task)."""
    from lagrseq.tasks import cube, grid

    try:
        if isinstance(task, cube.CubeStacking):
            return len(cube.partial_stack(prompt))
        shown = grid.partial_grid(prompt)
    except ValueError:
        return None
    if shown.shape != task.target.shape:
        return None
    return bin_of(task, shown)


def bin_size(task: Any) -> int:
    """The number a bin is a fraction of: the stack size, or the target's cells that are on."""
    from lagrseq.tasks import cube

    if isinstance(task, cube.CubeStacking):
        return int(task.stack_size)
    return int(np.count_nonzero(task.target))


def spread(patterns: Sequence[Any], bins: Sequence[int], n: int) -> list[Any]:
    """``n`` of ``patterns`` (at most all of them), taken from each bin in turn, in the order they
    were met within a bin, so that every bin is as evenly represented as it can be."""
    groups: dict[int, list[Any]] = {}
    for pattern, b in zip(patterns, bins):
        groups.setdefault(b, []).append(pattern)
    order = sorted(groups)
    chosen: list[Any] = []
    depth = 0
    while len(chosen) < min(n, len(patterns)):
        for b in order:
            if depth < len(groups[b]) and len(chosen) < n:
                chosen.append(groups[b][depth])
        depth += 1
    return chosen


def screen_queries(config: ExperimentConfig, prompts: int, runs: Sequence[str | Path] = (), warn: Callable[[str], None] | None = None) -> tuple[list[Any], int]:
    """(queries, answers per query) of a screen of ``prompts`` answers. Cube stacking: every
    prefix of the target, each asked ceil(N / prefixes) times. Grid tasks: N distinct states of
    the runs' ``/query`` records, spread over fill fractions, each asked once."""
    from lagrseq.running.recording import queries_for, record_patterns
    from lagrseq.running.wiring import make_task
    from lagrseq.tasks import cube

    if not 1 <= prompts <= MAX_PROMPTS:
        raise UsageError(f"--prompts {prompts}: expected 1 to {MAX_PROMPTS}")
    task = make_task(config)
    if isinstance(task, cube.CubeStacking) and not runs:
        prefixes = list(task.prefixes())
        return queries_for(config, prefixes), max(1, math.ceil(prompts / len(prefixes)))
    patterns = record_patterns(config, runs, "/query", warn)
    chosen = spread(patterns, [bin_of(task, p) for p in patterns], prompts)
    return queries_for(config, chosen), 1


# ------------------------------------------------------------------------------------------
# The model an answer came from: its GGUF header and sha256, kept in each answer's provenance
# ------------------------------------------------------------------------------------------
GGUF_MARK = "GGUF sha256 "


def model_provenance(model: Any, response_id: str | None) -> str:
    """``sample.provenance`` of a local model's answer: the server's response id, then the model
    file by its sha256 and header facts (a :class:`lagrseq.llm.gguf.Model`)."""
    header = model.header
    facts = ", ".join(
        str(value)
        for value in (
            header.get("general.name") if header else None,
            header.get("general.size_label") if header else None,
            header.quantization if header else None,
            header.architecture if header else None,
        )
        if value is not None
    )
    text = f"{response_id or 'llama.cpp'}; {GGUF_MARK}{model.sha256}; {facts}"
    return text[:1000]


def model_of_provenance(provenance: str | None) -> tuple[str | None, str | None]:
    """(sha256, header facts) of a provenance written by :func:`model_provenance` ((None, None)
    for any other)."""
    if not provenance or GGUF_MARK not in provenance:
        return None, None
    rest = provenance.split(GGUF_MARK, 1)[1]
    digest, _, facts = rest.partition("; ")
    digest = digest.strip()
    if len(digest) != 64 or any(c not in "0123456789abcdef" for c in digest):
        return None, None
    return digest, facts.strip() or None


def stamped_lines(lines: Iterable[str], model: Any) -> Iterator[str]:
    """JSONL lines of a local model's answers with each answer's provenance naming the model
    file (answers already stamped are left as they are)."""
    for line in lines:
        record = json.loads(line)
        sample = record["sample"]
        if model_of_provenance(sample.get("provenance"))[0] is None:
            sample["provenance"] = model_provenance(model, sample.get("provenance"))
        yield json.dumps(record, sort_keys=True, ensure_ascii=False, separators=(", ", ": "))


# ------------------------------------------------------------------------------------------
# Reading answers and counting them
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ScreenedAnswer:
    """One recorded answer, read through the task's parser."""

    model: str
    temperature: float
    bin: int
    size: int
    kind: str
    """``correct`` or another class of :func:`lagrseq.running.recording.classify`."""
    latency_s: float | None
    completion_tokens: int | None
    prompt_tokens: int | None
    finish_reason: str | None
    sha256: str | None
    facts: str | None
    counted: bool = True
    """It counts towards accuracy and answer kinds (False: at temperature 0, a repeat of an
    identical answer to the same prompt: greedy decoding gives the same answer again, not a new
    observation). Speed counts every answer."""


def read_answers(path: Path, config: ExperimentConfig) -> list[ScreenedAnswer]:
    """Every answer of ``config``'s task in the JSONL file ``path`` (checked line by line as an
    import is: one bad line refuses the file with one message), classified by the task's parser
    and placed in its bin by the prompt's pattern. At temperature 0 an answer repeated word for
    word to the same prompt counts once towards accuracy (:func:`_independent`)."""
    import tempfile

    from lagrseq.llm.store import RecordStore, import_jsonl_file
    from lagrseq.running.recording import classify
    from lagrseq.running.wiring import make_task

    task = make_task(config)
    size = bin_size(task)
    answers: list[ScreenedAnswer] = []
    with tempfile.TemporaryDirectory(prefix="lagrseq-screen-") as scratch:
        import_jsonl_file(path, Path(scratch) / "store", path.name)
        with RecordStore(Path(scratch) / "store", create=False) as store:
            for entry in store.entries():
                if entry.task != config.task.name:
                    continue
                where = bin_of_prompt(task, entry.prompt)
                if where is None:
                    raise UsageError(f"{path}: a {config.task.name} answer whose prompt shows no pattern of this task (key {entry.key[:12]}); screen only answers to the task's own prompts")
                counted = _independent(entry)
                for sample in entry.samples:
                    kind, _ = classify(task, sample.text)
                    digest, facts = model_of_provenance(sample.provenance)
                    usage = sample.usage
                    answers.append(
                        ScreenedAnswer(
                            model=str(entry.request["model"]),
                            temperature=float(entry.request["temperature"]),
                            bin=where,
                            size=size,
                            kind=kind,
                            latency_s=sample.latency_s,
                            completion_tokens=usage.completion_tokens if usage else None,
                            prompt_tokens=usage.prompt_tokens if usage else None,
                            finish_reason=sample.finish_reason,
                            sha256=digest,
                            facts=facts,
                            counted=any(sample is c for c in counted),
                        )
                    )
    return answers


def _independent(entry: Any) -> list[Any]:
    """The answers of one prompt that count as separate observations: at temperature 0 (greedy
    decoding) asking again repeats the same answer, so identical answers count once; at tau > 0
    each sample is a draw of its own."""
    if float(entry.request["temperature"]) != 0.0:
        return list(entry.samples)
    seen: set[str] = set()
    kept = []
    for sample in entry.samples:
        if sample.text not in seen:
            seen.add(sample.text)
            kept.append(sample)
    return kept


@dataclass
class Screen:
    """The answers of one model at one temperature on one task, counted."""

    task: str
    model: str
    temperature: float
    size: int
    cells: dict[int, tuple[int, int]] = field(default_factory=dict)
    """bin -> (answers, correct)."""
    kinds: dict[str, int] = field(default_factory=dict)
    sha256: str | None = None
    facts: str | None = None
    seconds: list[float] = field(default_factory=list)
    tokens: list[int] = field(default_factory=list)
    prompt_tokens: list[int] = field(default_factory=list)
    cut: int = 0
    """Answers that stopped at the token limit (finish reason ``length``)."""
    longest: int | None = None
    """The most tokens of prompt and answer together (compare with the server's context)."""

    @property
    def n(self) -> int:
        return sum(n for n, _ in self.cells.values())

    @property
    def correct(self) -> int:
        return sum(k for _, k in self.cells.values())

    def unshown(self) -> tuple[int, int]:
        """(answers, correct) on the prompts that do not already show the whole target (a cube
        prompt with the complete stack can be answered by repeating it)."""
        kept = [cell for b, cell in self.cells.items() if b < self.size]
        return sum(n for n, _ in kept), sum(k for _, k in kept)

    def seconds_per_answer(self) -> float | None:
        return float(np.mean(self.seconds)) if self.seconds else None

    def tokens_per_second(self) -> float | None:
        timed = [(t, s) for t, s in zip(self.tokens, self.seconds) if s > 0]
        if not timed:
            return None
        return float(sum(t for t, _ in timed) / sum(s for _, s in timed))

    def label(self) -> str:
        return f"{self.model} τ={self.temperature:g}"


def screens_of(task: str, answers: Iterable[ScreenedAnswer]) -> list[Screen]:
    """The answers grouped by model and temperature, in order of model then temperature."""
    screens: dict[tuple[str, float], Screen] = {}
    for a in answers:
        s = screens.setdefault((a.model, a.temperature), Screen(task, a.model, a.temperature, a.size))
        if a.counted:
            n, k = s.cells.get(a.bin, (0, 0))
            s.cells[a.bin] = (n + 1, k + (a.kind == "correct"))
            s.kinds[a.kind] = s.kinds.get(a.kind, 0) + 1
        s.sha256 = s.sha256 or a.sha256
        s.facts = s.facts or a.facts
        if a.latency_s is not None and a.completion_tokens is not None:
            s.seconds.append(a.latency_s)
            s.tokens.append(a.completion_tokens)
        if a.prompt_tokens is not None:
            s.prompt_tokens.append(a.prompt_tokens)
            total = a.prompt_tokens + (a.completion_tokens or 0)
            s.longest = total if s.longest is None else max(s.longest, total)
        s.cut += a.finish_reason == "length"
    return [screens[k] for k in sorted(screens)]


def bin_label(task: str, b: int, size: int) -> str:
    return f"{b}/{size} cubes" if task == "cube-stacking" else f"{b}/{size} cells"


def _percent(k: int, n: int) -> str:
    low, high = wilson(k, n)
    return f"{k}/{n} = {100 * k / n:.0f}% [{100 * low:.0f}, {100 * high:.0f}]" if n else "-"


def _kinds_text(kinds: dict[str, int]) -> str:
    from lagrseq.running.recording import REFUSALS

    order = ["correct", "wrong", "partial", *REFUSALS]
    return ", ".join(f"{name} {kinds[name]}" for name in order if kinds.get(name))


OVERALL_COLUMNS = ("task", "model", "τ", "model file (GGUF)", "sha256", "right (95% CI)", "right, target not in prompt", "answer kinds", "s/answer", "answer tokens/s", "cut at max_tokens", "longest prompt+answer")


def overall_rows(screens: Sequence[Screen]) -> list[tuple[str, ...]]:
    """One row per model, temperature and task (:data:`OVERALL_COLUMNS`)."""
    rows: list[tuple[str, ...]] = []
    for s in screens:
        spa, tps = s.seconds_per_answer(), s.tokens_per_second()
        n_unshown, k_unshown = s.unshown()
        rows.append((
            s.task, s.model, f"{s.temperature:g}", s.facts or "-", s.sha256[:12] if s.sha256 else "-",
            _percent(s.correct, s.n), _percent(k_unshown, n_unshown), _kinds_text(s.kinds),
            "-" if spa is None else f"{spa:.1f}", "-" if tps is None else f"{tps:.1f}", str(s.cut),
            "-" if s.longest is None else str(s.longest),
        ))
    return rows


def markdown(screens: Sequence[Screen]) -> list[str]:
    """Two Markdown tables: one row per model (overall accuracy with its Wilson 95% interval,
    the same without the prompts that show the whole target, answer kinds, speed: seconds per
    answer and answer tokens per second of the whole request, prompt included), then accuracy
    per bin (correct/n, percent, interval)."""
    lines = ["| " + " | ".join(OVERALL_COLUMNS) + " |", "|" + "---|" * len(OVERALL_COLUMNS)]
    lines += ["| " + " | ".join(row) + " |" for row in overall_rows(screens)]
    for task in sorted({s.task for s in screens}):
        group = [s for s in screens if s.task == task]
        bins = sorted({b for s in group for b in s.cells})
        size = group[0].size
        lines += ["", f"| {task}: shown | " + " | ".join(s.label() for s in group) + " |", "|---|" + "---|" * len(group)]
        for b in bins:
            cells = " | ".join(_percent(*reversed(s.cells[b])) if b in s.cells else "-" for s in group)
            lines.append(f"| {bin_label(task, b, size)} | {cells} |")
    return lines


CSV_FIELDS = ("task", "model", "temperature", "sha256", "model_file", "shown", "size", "fraction", "answers", "correct", "accuracy", "wilson_low", "wilson_high")


def csv_text(screens: Sequence[Screen]) -> str:
    """One CSV row per model, temperature and bin (``shown`` = bin; ``all`` for the whole screen)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_FIELDS)
    for s in screens:
        rows = [(str(b), b / s.size, *s.cells[b]) for b in sorted(s.cells)] + [("all", "", s.n, s.correct)]
        for shown, fraction, n, k in rows:
            low, high = wilson(int(k), int(n))
            fraction_text = f"{fraction:.4f}" if fraction != "" else ""
            writer.writerow([s.task, s.model, f"{s.temperature:g}", s.sha256 or "", s.facts or "", shown, s.size, fraction_text, n, k, f"{k / n:.4f}" if n else "", f"{low:.4f}", f"{high:.4f}"])
    return out.getvalue()


def figure(screens: Sequence[Screen]) -> Any:
    """Fig. 4-style: accuracy (%) against the fraction of the pattern shown, one panel per task,
    one line per model and temperature, each point with its Wilson 95% interval."""
    from matplotlib.figure import Figure

    from lagrseq.analysis.figures import COLORS, FIGSIZE

    tasks = sorted({s.task for s in screens})
    fig = Figure(figsize=(FIGSIZE[0] * len(tasks), FIGSIZE[1]), layout="constrained")
    axes = fig.subplots(1, len(tasks), squeeze=False)[0]
    markers = "osD^vP*X"
    for ax, task in zip(axes, tasks):
        group = [s for s in screens if s.task == task]
        for i, s in enumerate(group):
            bins = sorted(s.cells)
            x = np.array([b / s.size for b in bins]) + (i - (len(group) - 1) / 2) * 0.008
            acc = np.array([100 * s.cells[b][1] / s.cells[b][0] for b in bins])
            bounds = np.array([wilson(s.cells[b][1], s.cells[b][0]) for b in bins]) * 100
            err = np.vstack([np.maximum(acc - bounds[:, 0], 0), np.maximum(bounds[:, 1] - acc, 0)])
            ns = sorted({s.cells[b][0] for b in bins})
            per = f"n={ns[0]}" if len(ns) == 1 else f"n={ns[0]}-{ns[-1]}"
            ax.errorbar(x, acc, yerr=err, color=COLORS[i % len(COLORS)], marker=markers[i % len(markers)], markerfacecolor="none", capsize=3, linewidth=1.5, label=f"{s.label()} ({per} per point)")
        ax.set_title(f"{task}: open models, {'prefix' if task == 'cube-stacking' else 'pattern'} shown")
        ax.set_xlabel("Fraction of the pattern in the prompt")
        ax.set_ylabel("Right (%), Wilson 95% interval")
        ax.set_ylim(-3, 103)
        ax.set_xlim(-0.05, 1.05)
        ax.legend(fontsize="small", loc="center left", framealpha=0.9)
    return fig


# ------------------------------------------------------------------------------------------
# The two ways in: ask a model now (the answers kept as JSONL), or read JSONL recorded before
# ------------------------------------------------------------------------------------------
def record_screen(
    config: ExperimentConfig,
    provider: str,
    prompts: int,
    runs: Sequence[str | Path],
    store: Path | None,
    answers: Path,
    options: Any,
    bar_for: Callable[[int], Any],
    warn: Callable[[str], None] | None = None,
) -> str:
    """Ask ``provider`` the screen's prompts (topping up ``store``, or a temporary one), then write
    exactly those prompts' answers to ``answers`` as recorded-answer JSONL (written to a temporary
    name and renamed: a failure leaves no half file). A local model's answers name its file by
    GGUF header and sha256 in their provenance. Returns the line to print."""
    import shutil
    import tempfile

    from lagrseq.llm.store import RecordStore, jsonl_lines, query_key
    from lagrseq.running.recording import _local_endpoint, record, served_queries
    from lagrseq.running.wiring import local_settings, parse_provider, provider_kind

    queries, samples = screen_queries(config, prompts, runs, warn)
    kind = provider_kind(provider)
    model = None
    if kind.local_server:
        from lagrseq.llm.gguf import describe

        settings = local_settings(parse_provider(provider).argument, options)
        model = describe(settings.model, "local")
        if model.header is None:
            raise UsageError(f"local model {settings.model}: {model.problem}")
    answers = Path(answers)
    if answers.exists() and not answers.is_file():
        raise UsageError(f"--answers {answers}: not a regular file; give a .jsonl path to write")
    scratch = None if store is not None else Path(tempfile.mkdtemp(prefix="lagrseq-screen-store-"))
    store_path = store if store is not None else scratch / "store"  # type: ignore[operator]
    try:
        with bar_for(len(queries)) as bar:
            report = record(queries, store_path, samples, "new", options, bar, provider)
        if report.stopped is not None:
            raise report.stopped
        from lagrseq.llm.store import endpoint_of

        endpoint = _local_endpoint() if kind.local_server else endpoint_of(options.base_url)
        sent = served_queries(queries, kind.local_server or getattr(options, "server", None) == "llama.cpp")
        wanted = {query_key(q, endpoint)[0] for q in sent}
        with RecordStore(store_path, create=False) as opened:
            lines = [line for line in jsonl_lines(opened) if json.loads(line)["key"] in wanted]
        if model is not None:
            lines = list(stamped_lines(lines, model))
        partial = answers.with_name(answers.name + ".partial")
        try:
            answers.parent.mkdir(parents=True, exist_ok=True)
            partial.write_text("".join(line + "\n" for line in lines), encoding="utf-8")
            os.replace(partial, answers)
        except OSError as exc:
            with contextlib.suppress(OSError):
                partial.unlink()
            raise UsageError(f"cannot write {answers}: {exc.strerror or exc}") from None
    finally:
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)
    return f"{len(lines)} answers to {len(queries)} prompts written to {answers}"


def screens_from(files: Sequence[Path], configs: Sequence[ExperimentConfig]) -> list[Screen]:
    """The screens of every task of ``configs`` over the answers in ``files`` (JSONL). A file may
    hold answers of several tasks and models; a task none of the files answers is left out."""
    if not files:
        raise UsageError("no answer files given; give recorded-answer JSONL files (lagrseq screen --answers writes them)")
    if len(files) > MAX_ANSWER_FILES:
        raise UsageError(f"{len(files)} answer files; at most {MAX_ANSWER_FILES} at once")
    screens: list[Screen] = []
    for config in configs:
        answers: list[ScreenedAnswer] = []
        for path in files:
            answers.extend(read_answers(Path(path), config))
        screens.extend(screens_of(config.task.name, answers))
    return screens


def write_screen(screens: Sequence[Screen], out: Path, stem: str) -> list[Path]:
    """``OUT/STEM.md``, ``.csv`` and ``.png``; returns the paths written."""
    if not screens:
        raise UsageError("no answers of the task in the files given; nothing to screen")
    try:
        out.mkdir(parents=True, exist_ok=True)
        md, table, png = out / f"{stem}.md", out / f"{stem}.csv", out / f"{stem}.png"
        md.write_text("\n".join(markdown(screens)) + "\n", encoding="utf-8")
        table.write_text(csv_text(screens), encoding="utf-8")
        figure(screens).savefig(png, dpi=100, metadata={"Software": None})
    except OSError as exc:
        raise UsageError(f"cannot write the screen to {out}: {exc.strerror or exc}") from None
    return [md, table, png]


# ------------------------------------------------------------------------------------------
# The report's "open models" item: the screens and the temperature model's test, rebuilt from
# the committed recorded answers only (no extra, no model file)
# ------------------------------------------------------------------------------------------
SCREEN_FILES = "recorded_llm/screen-*.jsonl"
"""The screens' answers, relative to the directory lagrseq reproduce runs in (the repository root,
as for the suite's ``recorded:recorded_llm/...`` providers)."""
TEMPERATURE_FILES = "recorded_llm/qwen2.5-coder-1.5b-cube-t*.jsonl"
"""Real answers at several temperatures of the model that cleared the screen (Table 2's rows)."""
SCREEN_TASKS = ("cube-stacking", "object-arrangement")


def temperature_rows(screens: Sequence[Screen], model: Any) -> list[tuple[str, str, str, str, str, str]]:
    """The temperature model ``model`` (:class:`lagrseq.tasks.cube.TemperatureModel`) tested on
    real answers: for each temperature above 0 and prefix length, the accuracy it predicts from
    the same model's tau = 0 answers against the accuracy measured (with its Wilson interval), and
    whether the prediction lies inside the interval. Nothing is fitted to the tau > 0 answers."""
    rows: list[tuple[str, str, str, str, str, str]] = []
    by_model: dict[str, dict[float, Screen]] = {}
    for s in screens:
        by_model.setdefault(s.model, {})[s.temperature] = s
    for name, temps in sorted(by_model.items()):
        base = temps.get(0.0)
        if base is None:
            continue
        for tau in sorted(t for t in temps if t > 0):
            s = temps[tau]
            predicted_all, measured_n, measured_k = 0.0, 0, 0
            for b in sorted(s.cells):
                if b not in base.cells:
                    continue
                n0, k0 = base.cells[b]
                predicted = k0 / n0 * model.factor(b / s.size, tau)
                n, k = s.cells[b]
                low, high = wilson(k, n)
                predicted_all += predicted * n
                measured_n, measured_k = measured_n + n, measured_k + k
                rows.append((name, f"{tau:g}", bin_label(s.task, b, s.size), f"{100 * predicted:.0f}%", _percent(k, n), "yes" if low <= predicted <= high else "no"))
            if measured_n:
                predicted_mean = predicted_all / measured_n
                low, high = wilson(measured_k, measured_n)
                rows.append((name, f"{tau:g}", "all prefixes", f"{100 * predicted_mean:.0f}%", _percent(measured_k, measured_n), "yes" if low <= predicted_mean <= high else "no"))
    return rows


def _with_predictions(fig: Any, screens: Sequence[Screen], model: Any) -> Any:
    """Fig. 4-style picture of real answers at several temperatures with, dashed in each line's
    colour, what the temperature model predicts from the same model's tau = 0 answers."""
    from lagrseq.analysis.figures import COLORS

    ax = fig.axes[0]
    group = [s for s in screens if s.task == "cube-stacking"]
    base = {s.model: s for s in group if s.temperature == 0.0}
    for i, s in enumerate(group):
        zero = base.get(s.model)
        if s.temperature <= 0 or zero is None:
            continue
        bins = sorted(b for b in s.cells if b in zero.cells)
        predicted = [100 * zero.cells[b][1] / zero.cells[b][0] * model.factor(b / s.size, s.temperature) for b in bins]
        ax.plot([b / s.size for b in bins], predicted, color=COLORS[i % len(COLORS)], linestyle="--", linewidth=1.0, label=f"τ={s.temperature:g} predicted by the temperature model")
    ax.legend(fontsize="small", loc="center left", framealpha=0.9)
    return fig


def report_sections(root: Path | None = None) -> tuple[list[tuple[str, Any, Any]], str]:
    """The sections of the report's "open models" item, as (stem, table, figure or None), and a
    line saying what they were made of (or why there are none). The files are read under
    ``root``; by default under the current directory, else under the source checkout lagrseq was
    installed from (an editable install: ``reproduce`` started in another directory finds them)."""
    if root is None:
        from lagrseq.paths import source_checkout

        roots = [Path("."), source_checkout()]
        root = next((where for where in roots if any(where.glob(SCREEN_FILES))), roots[0])
        where = "here or in a lagrseq source checkout (a non-editable install ships none)"
    else:
        where = f"under {root}"
    import pandas as pd

    from lagrseq.analysis.tables import Table
    from lagrseq.running.recording import record_config
    from lagrseq.tasks.cube import AUTHORS_T0

    files = sorted(root.glob(SCREEN_FILES))
    if not files:
        return [], f"open models: not made: no {SCREEN_FILES} {where}: run lagrseq reproduce from a clone of the repository, or copy its recorded_llm/ folder here"
    configs = [record_config(task, "upstream", None, []) for task in SCREEN_TASKS]
    screens = screens_from(files, configs)
    data = pd.read_csv(io.StringIO(csv_text(screens)))
    sections: list[tuple[str, Any, Any]] = [
        (
            "open-models",
            Table(
                f"Open models: screen of {len({s.model for s in screens})} GGUF models at τ = 0 (provenance: open model; {len(files)} recorded answer files, {sum(s.n for s in screens)} answers)",
                OVERALL_COLUMNS,
                tuple(overall_rows(screens)),
                data,
            ),
            figure(screens),
        )
    ]
    cells: list[tuple[str, ...]] = []
    for s in screens:
        cells += [(s.task, s.label(), bin_label(s.task, b, s.size), _percent(s.cells[b][1], s.cells[b][0])) for b in sorted(s.cells)]
    sections.append(("open-models-cells", Table("Open models: right answers per prefix length / fill fraction (Wilson 95% interval)", ("task", "model", "shown", "right"), tuple(cells), data), None))
    temperature_files = sorted(root.glob(TEMPERATURE_FILES))
    if temperature_files and AUTHORS_T0.temperature is not None:
        real = screens_from(temperature_files, configs[:1])
        rows = temperature_rows(real, AUTHORS_T0.temperature)
        frame = pd.DataFrame(rows, columns=["model", "tau", "shown", "predicted", "measured", "inside"])
        sections.append(
            (
                "open-models-temperature",
                Table(
                    "Open models: the mock's temperature model (P(right | τ) = P(right | 0) × (1 - τ·drop)) tested on real τ > 0 answers, not refitted",
                    ("model", "τ", "shown", "predicted from τ = 0", "measured (95% CI)", "prediction inside CI"),
                    tuple(rows),
                    frame,
                ),
                _with_predictions(figure(real), real, AUTHORS_T0.temperature),
            )
        )
    return sections, f"open models: {len(files)} recorded answer files, {sum(s.n for s in screens)} answers of {len({s.model for s in screens})} models"
