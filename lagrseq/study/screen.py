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

import csv
import io
import json
import math
import re
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lagrseq import outputs
from lagrseq.config import ExperimentConfig
from lagrseq.errors import UsageError
from lagrseq.progress import Reporter
from lagrseq.text import csv_cell, markdown_cell

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


PROMPT_SETS = ("prefixes", "relabelled", "runs", "sampled")
"""``lagrseq screen --prompt-set``: ``prefixes`` (cube stacking, the default: every prefix of the
target, nested, so the screen is a complete count over one sequence, not a sample of prompts);
``relabelled`` (cube stacking: N distinct relabelled cube sets, one prompt each, no two sharing a
target); ``runs`` (grid tasks, the default: N distinct states met in ``--from-runs``); ``sampled``
(grid tasks: N distinct partial states of the target, drawn without runs)."""
PROMPT_SEED = 34
"""Seeds the relabellings and sampled states together with ``--seed`` (the prompt sets)."""


def screen_queries(
    config: ExperimentConfig,
    prompts: int,
    runs: Sequence[str | Path] = (),
    reporter: Reporter | None = None,
    prompt_set: str | None = None,
    seed: int = 0,
) -> tuple[list[Any], int]:
    """(queries, answers per query) of a screen of ``prompts`` answers (:data:`PROMPT_SETS`).
    Cube stacking: every prefix of the target, each asked ceil(N / prefixes) times; or N
    relabelled cube sets (:func:`relabelled_patterns`), each asked once. Grid tasks: N distinct
    states of the runs' ``/query`` records, or N sampled partial states of the target
    (:func:`sampled_states`), spread over fill fractions, each asked once. ``reporter`` is warned
    about each run log left out."""
    from lagrseq.loop.lagr import query_for
    from lagrseq.running.recording import queries_for, record_patterns
    from lagrseq.running.wiring import make_task
    from lagrseq.tasks import cube

    if not 1 <= prompts <= MAX_PROMPTS:
        raise UsageError(f"--prompts {prompts}: expected 1 to {MAX_PROMPTS}")
    task = make_task(config)
    is_cube = isinstance(task, cube.CubeStacking)
    chosen_set = prompt_set or ("prefixes" if is_cube and not runs else "runs")
    allowed = ("prefixes", "relabelled", "runs") if is_cube else ("runs", "sampled")
    if chosen_set not in allowed:
        raise UsageError(f"--prompt-set {chosen_set}: {config.task.name} screens take {', '.join(allowed)}")
    if (chosen_set == "runs") != bool(runs):
        raise UsageError(
            "--prompt-set runs needs --from-runs RUNS (the runs whose states are screened)" if not runs
            else f"--from-runs belongs to --prompt-set runs, not {chosen_set}: leave it out"
        )
    if chosen_set == "prefixes":
        prefixes = list(task.prefixes())  # type: ignore[attr-defined]
        return queries_for(config, prefixes), max(1, math.ceil(prompts / len(prefixes)))
    if chosen_set == "relabelled":
        pairs = relabelled_patterns(int(task.stack_size), prompts, seed)  # type: ignore[attr-defined]
        return [query_for(t, config.llm, pattern) for t, pattern in pairs], 1
    if chosen_set == "sampled":
        return queries_for(config, sampled_states(task, prompts, seed)), 1
    patterns = record_patterns(config, runs, "/query", reporter)
    chosen = spread(patterns, [bin_of(task, p) for p in patterns], prompts)
    return queries_for(config, chosen), 1


def relabelled_patterns(stack_size: int, prompts: int, seed: int = 0) -> list[tuple[Any, tuple[int, ...]]]:
    """``prompts`` (task, shown stack) pairs for a screen that is a sample of prompts: each a
    distinct relabelling of the ``stack_size`` cubes (the same cubes and rule under other
    letters: :attr:`lagrseq.tasks.cube.CubeStacking.relabel`; never the released letters), showing
    a prefix of 1 to N - 1 cubes of its own target in turn, so no two prompts are prefixes of one
    target and none shows the whole answer. Seeded by ``seed``."""
    from lagrseq.tasks import cube

    most = math.factorial(stack_size) - 1
    if prompts > most:
        raise UsageError(f"--prompts {prompts}: {stack_size} cubes have only {most} relabellings; ask for at most {most}")
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([PROMPT_SEED, int(seed), stack_size])))
    identity = tuple(range(stack_size))
    seen: set[tuple[int, ...]] = {identity}
    pairs: list[tuple[Any, tuple[int, ...]]] = []
    while len(pairs) < prompts:
        relabel = tuple(int(i) for i in rng.permutation(stack_size))
        if relabel in seen:
            continue
        seen.add(relabel)
        task = cube.CubeStacking(stack_size, relabel=relabel)
        shown = 1 + len(pairs) % (stack_size - 1)
        pairs.append((task, task.target[:shown]))
    return pairs


MAX_SAMPLED_CELLS = 16
"""A target with more cells on than this is not sampled (its subsets are enumerated)."""


def sampled_states(task: Any, prompts: int, seed: int = 0) -> list[Any]:
    """``prompts`` distinct partial states of a grid task's target, drawn without runs: every
    subset of the target's cells short of the whole, in a seeded order, spread over how many of
    its cells are shown (:func:`spread`). The target's own values fill the cells shown; nothing
    else is on the grid."""
    target = np.asarray(task.target)
    on = [tuple(int(v) for v in cell) for cell in np.argwhere(target != 0)]
    if len(on) > MAX_SAMPLED_CELLS:
        raise UsageError(f"the target has {len(on)} cells on; --prompt-set sampled takes targets of at most {MAX_SAMPLED_CELLS}")
    subsets = [mask for mask in range(2 ** len(on) - 1)]  # every subset but the whole target
    if prompts > len(subsets):
        raise UsageError(f"--prompts {prompts}: the target has only {len(subsets)} partial states; ask for at most {len(subsets)}")
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([PROMPT_SEED, int(seed), len(on)])))
    order = [subsets[i] for i in rng.permutation(len(subsets))]
    states = []
    for mask in order:
        state = np.zeros_like(target)
        for bit, (r, c) in enumerate(on):
            if mask >> bit & 1:
                state[r, c] = target[r, c]
        states.append(state)
    return spread(states, [bin_of(task, state) for state in states], prompts)


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
    prompt: str = ""
    """The record key of the prompt it answers (answers cluster by prompt)."""
    prompt_set: str = ""
    """Which kind of prompts (:func:`task_of_entry`): "" for the prefixes of the configured cube
    target or a grid task's states; otherwise e.g. ``relabelled 8-cube sets``."""
    pinned: bool = False
    """The request pinned llama.cpp's samplers (its key holds ``top_k``, ``min_p``,
    ``repeat_penalty``): answers of another distribution than those recorded with its defaults,
    so never pooled with them."""


def read_answers(path: Path, config: ExperimentConfig) -> list[ScreenedAnswer]:
    """Every answer of ``config``'s task in the JSONL file ``path`` (checked line by line as an
    import is: one bad line refuses the file with one message), classified by the task's parser
    and placed in its bin by the prompt's pattern. At temperature 0 an answer repeated word for
    word to the same prompt counts once towards accuracy (:func:`_independent`)."""
    import tempfile

    from lagrseq.llm.store import RecordStore, import_jsonl_file
    from lagrseq.running.recording import classify
    from lagrseq.running.wiring import make_task

    configured = make_task(config)
    answers: list[ScreenedAnswer] = []
    # a grid prompt does not name its target: the configured one judges it, and is named when it
    # is not the task's default
    target = getattr(config.task, "target", None)
    other_target = f"{target} target" if target is not None and target != getattr(type(config.task)(), "target", None) else ""
    with tempfile.TemporaryDirectory(prefix="lagrseq-screen-") as scratch:
        import_jsonl_file(path, Path(scratch) / "store", path.name)
        with RecordStore(Path(scratch) / "store", create=False) as store:
            for entry in store.entries():
                if entry.task != config.task.name:
                    continue
                task, prompt_set = task_of_entry(configured, entry.prompt)
                if task is not None and not prompt_set and other_target:
                    prompt_set = other_target
                if task is not None and not isinstance(task, _cube_class()) and SAMPLED_TAG.search(path.name):
                    prompt_set = ", ".join(part for part in (SAMPLED_SET, prompt_set) if part)
                where = None if task is None else bin_of_prompt(task, entry.prompt)
                if task is None or where is None:
                    raise UsageError(f"{path}: a {config.task.name} answer whose prompt shows no pattern of this task (key {entry.key[:12]}); screen only answers to the task's own prompts")
                size = bin_size(task)
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
                            prompt=entry.key,
                            prompt_set=prompt_set,
                            pinned=any(name in entry.request for name in ("top_k", "min_p", "repeat_penalty")),
                        )
                    )
    return answers


SAMPLED_SET = "sampled states"
"""The prompt set of a grid screen whose states were drawn from the target (``--prompt-set
sampled``), not met by runs: a file named ``screen-sampled-...`` (a grid prompt names neither)."""
SAMPLED_TAG = re.compile(r"(?:^|-)sampled-")


def _cube_class() -> type:
    from lagrseq.tasks.cube import CubeStacking

    return CubeStacking


def task_of_entry(configured: Any, prompt: str) -> tuple[Any, str]:
    """(task, prompt set) of a recorded prompt: a cube prompt is judged by the cube set it
    describes (:func:`lagrseq.tasks.cube.task_of_prompt`: the 11-cube target, a relabelled set),
    a grid prompt by the configured task (its prompt does not name the target). (None, "") for a
    cube prompt that describes no known cube set."""
    from lagrseq.tasks import cube

    if not isinstance(configured, cube.CubeStacking):
        return configured, ""
    try:
        task = cube.task_of_prompt(prompt)
    except ValueError:
        return None, ""
    if task.relabel is not None:
        return task, f"relabelled {task.stack_size}-cube sets"
    return task, "" if task.stack_size == configured.stack_size else f"{task.stack_size}-cube target's prefixes"


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
    prompt_set: str = ""
    """:attr:`ScreenedAnswer.prompt_set` of every answer in it."""
    pinned: bool = False
    """:attr:`ScreenedAnswer.pinned` of every answer in it."""
    cells: dict[int, tuple[int, int]] = field(default_factory=dict)
    """bin -> (answers, correct)."""
    prompts: dict[str, tuple[int, int]] = field(default_factory=dict)
    """prompt (record key) -> (answers, correct): the clusters an interval resamples."""
    prompt_bins: dict[str, int] = field(default_factory=dict)
    """prompt (record key) -> its bin."""
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

    @property
    def nested(self) -> bool:
        """Every prompt is a prefix of one cube target: the screen counts one sequence completely
        (there are no other prompts of it to sample), so its accuracy gets no sampling interval."""
        return self.task == "cube-stacking" and not self.prompt_set.startswith("relabelled")

    @property
    def from_runs(self) -> bool:
        """A grid screen of the states the runs' trajectories met (``--prompt-set runs``): states
        of a few trajectories, each following from the last, not a sample of states, so its
        accuracy gets no binomial interval."""
        return self.task != "cube-stacking" and not self.prompt_set.startswith(SAMPLED_SET)

    @property
    def kind(self) -> str:
        """The prompt set and, when pinned, the samplers: what tells two screens of one model and
        temperature apart ("" for the default prompts with the server's own samplers)."""
        return ", ".join(part for part in (self.prompt_set, "samplers pinned" if self.pinned else "") if part)

    def label(self) -> str:
        base = f"{self.model} τ={self.temperature:g}"
        return f"{base} ({self.kind})" if self.kind else base


def screens_of(task: str, answers: Iterable[ScreenedAnswer]) -> list[Screen]:
    """The answers grouped by model and temperature, in order of model then temperature."""
    screens: dict[tuple[str, float, str, bool], Screen] = {}
    for a in answers:
        s = screens.setdefault((a.model, a.temperature, a.prompt_set, a.pinned), Screen(task, a.model, a.temperature, a.size, a.prompt_set, a.pinned))
        if a.counted:
            n, k = s.cells.get(a.bin, (0, 0))
            s.cells[a.bin] = (n + 1, k + (a.kind == "correct"))
            n, k = s.prompts.get(a.prompt, (0, 0))
            s.prompts[a.prompt] = (n + 1, k + (a.kind == "correct"))
            s.prompt_bins[a.prompt] = a.bin
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


def _percent(k: int, n: int, interval: bool = True) -> str:
    """``k/n = x% [low, high]`` with the Wilson 95% interval rounded outward; without
    ``interval`` (answers that are no sample) the count alone."""
    if not n:
        return "-"
    if not interval:
        return f"{k}/{n} = {100 * k / n:.0f}%"
    low, high = wilson(k, n)
    return f"{k}/{n} = {100 * k / n:.0f}% {_bounds(low, high)}"


# ------------------------------------------------------------------------------------------
# Evidence sized right: intervals clustered by prompt, exact comparisons, the
# temperature model's likelihood-ratio test
# ------------------------------------------------------------------------------------------
RESAMPLES = 10_000
"""Resamples of a cluster bootstrap and of the temperature model's parametric bootstrap."""


@dataclass(frozen=True)
class Accuracy:
    """A screen's right answers over its prompts, with the interval its prompts allow."""

    correct: int
    answers: int
    prompts: int
    low: float | None
    high: float | None
    method: str
    """``complete count`` (nested prefixes of one target: no interval), ``cluster bootstrap``
    (prompts resampled, percentile), ``cluster bootstrap, widened to exact`` (the exact interval
    where it is wider, as it is with few right answers, where a percentile bootstrap under-covers:
    Clopper-Pearson with one answer per prompt, else at the clustered sample's effective size,
    :func:`_korn_graubard`), or ``exact over prompts`` (every prompt all right or all wrong: the
    bootstrap has nothing to resample)."""

    def text(self) -> str:
        if not self.answers:
            return "-"
        rate = f"{self.correct}/{self.answers} = {100 * self.correct / self.answers:.0f}%"
        if self.method == TRAJECTORY_STATES:
            return f"{rate} ({self.prompts} states met by the runs' trajectories: not a sample of states; no interval)"
        if self.low is None or self.high is None:
            return f"{rate} ({self.prompts} prefixes of one target: a count over one sequence, not a sample of prompts; no interval)"
        return f"{rate} {_bounds(self.low, self.high)} ({self.method}, {self.prompts} prompts)"


TRAJECTORY_STATES = "states of trajectories"
"""The method of a screen of the states runs met (:attr:`Screen.from_runs`): no interval."""


def _bounds(low: float, high: float) -> str:
    """``[low, high]`` in percent, rounded outward (an upper bound of 6.38% prints 7)."""
    from lagrseq.analysis.tables import interval

    return interval(100 * low, 100 * high, 0)


def _exact(successes: int, n: int) -> tuple[float, float]:
    from scipy.stats import binomtest

    ci = binomtest(successes, n).proportion_ci(0.95, method="exact")
    return float(ci.low), float(ci.high)


def unshown_part(s: Screen) -> Screen:
    """``s`` without the prompts that show the whole target (a cube prompt with the complete
    stack can be answered by repeating it)."""
    from dataclasses import replace

    keep = {key: cell for key, cell in s.prompts.items() if s.prompt_bins.get(key, 0) < s.size}
    return replace(s, cells={b: c for b, c in s.cells.items() if b < s.size}, prompts=keep, prompt_bins={key: s.prompt_bins[key] for key in keep})


def accuracy_over_prompts(s: Screen, resamples: int = RESAMPLES) -> Accuracy:
    """Right answers of ``s`` with an interval clustered by prompt: the prompts are resampled,
    not the answers (the answers to one prompt share it), with the generator
    :func:`lagrseq.analysis.stats.generator` keyed by task, model, temperature and prompt set.
    A screen of nested prefixes of one target (:attr:`Screen.nested`) is a complete count of
    that one sequence and gets no interval."""
    from lagrseq.analysis.stats import generator

    table = np.array(list(s.prompts.values()), dtype=np.int64).reshape(-1, 2)
    m = len(table)
    n, k = (int(v) for v in table.sum(axis=0)) if m else (0, 0)
    if s.nested or m == 0:
        return Accuracy(k, n, m, None, None, "complete count")
    if s.from_runs:
        return Accuracy(k, n, m, None, None, TRAJECTORY_STATES)
    sizes, right = table[:, 0], table[:, 1]
    if np.all(right == 0) or np.all(right == sizes):
        low, high = _exact(int(np.count_nonzero(right)), m)
        return Accuracy(k, n, m, low, high, "exact over prompts")
    rng = generator(f"open-models/{s.task}/{s.model}/{s.temperature:g}/{s.kind}")
    picks = rng.integers(m, size=(resamples, m))
    rates = right[picks].sum(axis=1) / sizes[picks].sum(axis=1)
    low, high = (float(v) for v in np.percentile(rates, [2.5, 97.5]))
    method = "cluster bootstrap"
    exact_low, exact_high = _exact(k, n) if np.all(sizes == 1) else _korn_graubard(right, sizes)
    if exact_low < low or exact_high > high:
        low, high, method = min(low, exact_low), max(high, exact_high), "cluster bootstrap, widened to exact"
    return Accuracy(k, n, m, low, high, method)


def _korn_graubard(right: np.ndarray, sizes: np.ndarray) -> tuple[float, float]:
    """The Clopper-Pearson interval at the clustered sample's effective size (Korn and Graubard,
    1998): n_eff = r(1 - r) / var(r), var(r) the ratio estimator's between-prompt variance, at most
    the answers; x_eff = r n_eff; Beta quantiles (``scipy.stats.beta``) for the fractional counts.
    Where a percentile bootstrap of few clustered right answers under-covers, this holds
    (benchmarks/open_models_coverage.py)."""
    from scipy.stats import beta

    m, total = len(right), float(sizes.sum())
    r = float(right.sum()) / total
    variance = m / (m - 1) * float(np.sum((right - r * sizes) ** 2)) / total**2 if m > 1 else 0.0
    n_eff = min(total, r * (1 - r) / variance) if variance > 0 else total
    x = r * n_eff
    low = 0.0 if x <= 0 else float(beta.ppf(0.025, x, n_eff - x + 1))
    high = 1.0 if x >= n_eff else float(beta.ppf(0.975, x + 1, n_eff - x))
    return low, high


def prompt_units(s: Screen, unshown: bool = False) -> tuple[int, int]:
    """(prompts, prompts right) of a screen: one unit per prompt, right when at least half its
    counted answers are (at tau = 0 a repeated identical answer counts once, so mostly one answer
    per prompt). ``unshown``: without the prompts that show the whole target."""
    kept = [cell for key, cell in s.prompts.items() if not unshown or s.prompt_bins.get(key, 0) < s.size]
    return len(kept), sum(1 for n, k in kept if n and 2 * k >= n)


def fisher_rows(screens: Sequence[Screen]) -> list[tuple[str, ...]]:
    """Per task, prompt set and temperature, the model right on the most prompts against each
    other model: prompts right of each, one unit per prompt in both arms (:func:`prompt_units`;
    never one arm's prompts against the other's answers), and Fisher's exact two-sided p
    (``scipy.stats.fisher_exact``); beside it the same without the prompts that show the target."""
    from scipy.stats import fisher_exact

    rows: list[tuple[str, ...]] = []
    groups: dict[tuple[str, str, float], list[Screen]] = {}
    for s in screens:
        groups.setdefault((s.task, s.kind, s.temperature), []).append(s)
    for (task, prompt_set, tau), group in sorted(groups.items()):
        if len(group) < 2:
            continue
        units = {id(g): prompt_units(g) for g in group}
        best = max(group, key=lambda g: (units[id(g)][1] / units[id(g)][0] if units[id(g)][0] else 0.0, units[id(g)][1]))
        bm, bk = units[id(best)]
        for other in group:
            if other is best:
                continue
            om, ok = units[id(other)]
            p = float(fisher_exact([[bk, bm - bk], [ok, om - ok]]).pvalue)
            row = [task, prompt_set or "-", f"{tau:g}", best.model, f"{bk}/{bm}", other.model, f"{ok}/{om}", f"{p:.3f}"]
            (bn, bu), (on, ou) = prompt_units(best, True), prompt_units(other, True)
            if (bn, on) != (bm, om) and bn and on:
                row += [f"{bu}/{bn} against {ou}/{on}: {float(fisher_exact([[bu, bn - bu], [ou, on - ou]]).pvalue):.3f}"]
            else:
                row += ["(no prompt shows the target)"]
            rows.append(tuple(row))
    return rows


FISHER_COLUMNS = ("task", "prompt set", "τ", "model right on most prompts", "prompts right", "against", "prompts right", "Fisher exact p (two-sided, one unit per prompt)", "target not in prompt: prompts right, p")


@dataclass(frozen=True)
class TemperatureTest:
    """The temperature model's predictions per prefix against real answers at one temperature."""

    model: str
    temperature: float
    prefixes: int
    answers: int
    statistic: float
    """The likelihood-ratio statistic G = 2 sum over prefixes of k log(k / n p) + (n - k) log((n - k) / n (1 - p)):
    the model (nothing fitted) against one free P(right) per prefix (the answers cluster by prefix)."""
    p_chi2: float
    """P(chi-square with ``prefixes`` degrees of freedom >= G)."""
    p_bootstrap: float
    """Parametric bootstrap: (1 + #{G* >= G}) / (1 + resamples), answers drawn from the model."""
    impossible: tuple[str, ...]
    """Prefixes where the model gives right answers probability 0 (or wrong ones 0) and the real
    answers hold some: the model is falsified there, whatever the rest."""
    possible_prefixes: int = 0
    """The prefixes left when those are set aside."""
    p_possible: float | None = None
    """The parametric-bootstrap p of the same test on those prefixes alone (None: none left or
    none set aside): how the model does where it is not falsified outright."""
    resamples: int = RESAMPLES

    def verdict(self) -> str:
        if self.impossible:
            rest = ""
            if self.p_possible is not None:
                rest = f"; on the other {self.possible_prefixes} prefixes p = {_p_text(self.p_possible, self.resamples)} ({'rejected' if self.p_possible < 0.05 else 'not rejected'} at 5%)"
            return "falsified: it predicts exactly 0 where real answers are right (" + "; ".join(self.impossible) + ")" + rest
        if self.p_bootstrap < 0.05:
            return "rejected at 5% (parametric bootstrap)"
        return "not rejected at 5%"


def _p_text(p: float, resamples: int) -> str:
    """A bootstrap p: at its floor 1 / (resamples + 1) it is a bound, not a value."""
    return f"< {2 / (resamples + 1):.1g}" if p <= 1 / (resamples + 1) + 1e-12 else f"{p:.2g}"


def _g_statistic(k: np.ndarray, n: np.ndarray, p: np.ndarray) -> np.ndarray:
    """G over the last axis; infinite where p gives an observed outcome probability 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        right = np.where(k > 0, k * np.log(k / (n * p)), 0.0)
        wrong = np.where(n - k > 0, (n - k) * np.log((n - k) / (n * (1 - p))), 0.0)
    return 2.0 * np.sum(right + wrong, axis=-1)


def _by_model_and_temperature(screens: Sequence[Screen]) -> list[tuple[str, dict[float, Screen]]]:
    """(model name, with its kind of prompts where it has one; temperature -> screen), by name."""
    by_model: dict[str, dict[float, Screen]] = {}
    for s in screens:
        by_model.setdefault(f"{s.model} ({s.kind})" if s.kind else s.model, {})[s.temperature] = s
    return sorted(by_model.items())


def temperature_tests(screens: Sequence[Screen], model: Any, resamples: int = RESAMPLES) -> list[TemperatureTest]:
    """The temperature model ``model`` tested at every temperature above 0 of every model that
    has tau = 0 answers: its P(right | prefix, tau) = P(right | prefix, 0) x factor, with P(right |
    prefix, 0) the same model's tau = 0 accuracy there (nothing fitted to the tau > 0 answers),
    against the real answers by a likelihood-ratio test per prefix (chi-square and parametric
    bootstrap p; seeded with :func:`lagrseq.analysis.stats.generator`)."""
    from scipy.stats import chi2

    from lagrseq.analysis.stats import generator

    tests: list[TemperatureTest] = []
    for name, temps in _by_model_and_temperature(screens):
        base = temps.get(0.0)
        if base is None:
            continue
        for tau in sorted(t for t in temps if t > 0):
            s = temps[tau]
            bins = [b for b in sorted(s.cells) if b in base.cells]
            if not bins:
                continue
            n = np.array([s.cells[b][0] for b in bins], dtype=float)
            k = np.array([s.cells[b][1] for b in bins], dtype=float)
            p = np.array([base.cells[b][1] / base.cells[b][0] * model.factor(b / s.size, tau) for b in bins])
            impossible = tuple(
                f"{bin_label(s.task, b, s.size)}: predicted {100 * pb:.0f}%, {int(kb)}/{int(nb)} right"
                for b, pb, kb, nb in zip(bins, p, k, n)
                if (pb <= 0 and kb > 0) or (pb >= 1 and kb < nb)
            )
            g = float(_g_statistic(k, n, p))
            p_chi2 = float(chi2.sf(g, len(bins))) if math.isfinite(g) else 0.0
            rng = generator(f"open-models-temperature/{name}/{tau:g}")
            simulated = rng.binomial(n.astype(np.int64), np.clip(p, 0.0, 1.0), size=(resamples, len(bins))).astype(float)
            g_star = _g_statistic(simulated, n, p)
            p_boot = float((1 + np.count_nonzero(g_star >= g)) / (1 + resamples))
            possible = np.array([not ((pb <= 0 and kb > 0) or (pb >= 1 and kb < nb)) for pb, kb, nb in zip(p, k, n)])
            p_rest = None
            if impossible and possible.any():
                g_rest = float(_g_statistic(k[possible], n[possible], p[possible]))
                p_rest = float((1 + np.count_nonzero(_g_statistic(simulated[:, possible], n[possible], p[possible]) >= g_rest)) / (1 + resamples))
            tests.append(TemperatureTest(name, tau, len(bins), int(n.sum()), g, p_chi2, p_boot, impossible, int(possible.sum()), p_rest, resamples))
    return tests


TEST_COLUMNS = ("model", "τ", "prefixes", "answers", "G (likelihood ratio)", "df", "p (chi-square)", "p (parametric bootstrap)", "result")


def temperature_test_rows(tests: Sequence[TemperatureTest]) -> list[tuple[str, ...]]:
    return [
        (t.model, f"{t.temperature:g}", str(t.prefixes), str(t.answers), "∞" if not math.isfinite(t.statistic) else f"{t.statistic:.1f}", str(t.prefixes), "0 (G infinite)" if not math.isfinite(t.statistic) else f"{t.p_chi2:.2g}", _p_text(t.p_bootstrap, t.resamples), t.verdict())
        for t in tests
    ]


def _kinds_text(kinds: dict[str, int]) -> str:
    from lagrseq.running.recording import REFUSALS

    order = ["correct", "wrong", "partial", *REFUSALS]
    return ", ".join(f"{name} {kinds[name]}" for name in order if kinds.get(name))


OVERALL_COLUMNS = ("task", "model", "τ", "model file (GGUF)", "sha256", "right (95% interval over prompts)", "right, target not in prompt", "answer kinds", "s/answer", "answer tokens/s", "cut at max_tokens", "longest prompt+answer")


def overall_rows(screens: Sequence[Screen]) -> list[tuple[str, ...]]:
    """One row per model, temperature and task (:data:`OVERALL_COLUMNS`)."""
    rows: list[tuple[str, ...]] = []
    for s in screens:
        spa, tps = s.seconds_per_answer(), s.tokens_per_second()
        rows.append((
            s.task, s.model + (f" ({s.kind})" if s.kind else ""), f"{s.temperature:g}", s.facts or "-", s.sha256[:12] if s.sha256 else "-",
            accuracy_over_prompts(s).text(), accuracy_over_prompts(unshown_part(s)).text(), _kinds_text(s.kinds),
            "-" if spa is None else f"{spa:.1f}", "-" if tps is None else f"{tps:.1f}", str(s.cut),
            "-" if s.longest is None else str(s.longest),
        ))
    return rows


def markdown(screens: Sequence[Screen]) -> list[str]:
    """Two Markdown tables: one row per model (overall accuracy with its interval over prompts,
    :func:`accuracy_over_prompts`,
    the same without the prompts that show the whole target, answer kinds, speed: seconds per
    answer and answer tokens per second of the whole request, prompt included), then accuracy
    per bin (correct/n, percent, interval)."""
    lines = ["| " + " | ".join(OVERALL_COLUMNS) + " |", "|" + "---|" * len(OVERALL_COLUMNS)]
    lines += ["| " + " | ".join(markdown_cell(c) for c in row) + " |" for row in overall_rows(screens)]
    for task in sorted({s.task for s in screens}):
        group = [s for s in screens if s.task == task]
        bins = sorted({b for s in group for b in s.cells})
        size = group[0].size
        lines += ["", f"| {task}: shown | " + " | ".join(markdown_cell(s.label()) for s in group) + " |", "|---|" + "---|" * len(group)]
        for b in bins:
            cells = " | ".join(_percent(s.cells[b][1], s.cells[b][0], interval=not s.from_runs) if b in s.cells else "-" for s in group)
            lines.append(f"| {bin_label(task, b, size)} | {cells} |")
    return lines


CSV_FIELDS = ("task", "model", "temperature", "prompt_set", "sha256", "model_file", "shown", "size", "fraction", "prompts", "answers", "correct", "accuracy", "interval", "low", "high")


def csv_text(screens: Sequence[Screen]) -> str:
    """One CSV row per model, temperature, prompt set and bin (``shown`` = bin: a Wilson 95%
    interval over its counted answers; none for states of trajectories), and one for the whole screen (``shown`` = ``all``: the
    interval over prompts of :func:`accuracy_over_prompts`, none for nested prefixes)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_FIELDS)
    for s in screens:
        per_bin: dict[int, int] = {}
        for b in s.prompt_bins.values():
            per_bin[b] = per_bin.get(b, 0) + 1
        head = [csv_cell(c) for c in (s.task, s.model, f"{s.temperature:g}", s.kind, s.sha256 or "", s.facts or "")]
        for b in sorted(s.cells):
            n, k = s.cells[b]
            shown = [TRAJECTORY_STATES, "", ""] if s.from_runs else ["wilson", *(f"{v:.4f}" for v in wilson(k, n))]
            writer.writerow([*head, str(b), s.size, f"{b / s.size:.4f}", per_bin.get(b, 0), n, k, f"{k / n:.4f}" if n else "", *shown])
        total = accuracy_over_prompts(s)
        bounds = ["", ""] if total.low is None or total.high is None else [f"{total.low:.4f}", f"{total.high:.4f}"]
        writer.writerow([*head, "all", s.size, "", total.prompts, total.answers, total.correct, f"{total.correct / total.answers:.4f}" if total.answers else "", total.method, *bounds])
    return out.getvalue()


def figure(screens: Sequence[Screen]) -> Any:
    """Fig. 4-style: accuracy (%) against the fraction of the pattern shown, one panel per task,
    one line per model and temperature, each point with its Wilson 95% interval (none for the
    states of trajectories, :attr:`Screen.from_runs`)."""
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
            err = None if s.from_runs else np.vstack([np.maximum(acc - bounds[:, 0], 0), np.maximum(bounds[:, 1] - acc, 0)])
            ns = sorted({s.cells[b][0] for b in bins})
            per = f"n={ns[0]}" if len(ns) == 1 else f"n={ns[0]}-{ns[-1]}"
            ax.errorbar(x, acc, yerr=err, color=COLORS[i % len(COLORS)], marker=markers[i % len(markers)], markerfacecolor="none", capsize=3, linewidth=1.5, label=f"{s.label()} ({per} per point)")
        ax.set_title(f"{task}: open models, {'prefix' if task == 'cube-stacking' else 'pattern'} shown")
        ax.set_xlabel("Fraction of the pattern in the prompt")
        ax.set_ylabel("Right (%), Wilson 95% interval (none for states of trajectories)")
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
    reporter: Reporter | None = None,
    prompt_set: str | None = None,
    seed: int = 0,
) -> str:
    """Ask ``provider`` the screen's prompts (topping up ``store``, or a temporary one), then write
    exactly those prompts' answers to ``answers`` as recorded-answer JSONL (written to a temporary
    name and renamed: a failure leaves no half file). An existing ``answers`` is refused before
    anything is asked, never truncated nor appended to; a symbolic link there too. A local model's answers name its file by
    GGUF header and sha256 in their provenance. Returns the line to print."""
    import shutil
    import tempfile

    from lagrseq.llm.store import RecordStore, jsonl_lines, query_key
    from lagrseq.running.recording import _local_endpoint, record, served_queries
    from lagrseq.running.wiring import local_settings, parse_provider, provider_kind

    queries, samples = screen_queries(config, prompts, runs, reporter, prompt_set, seed)
    kind = provider_kind(provider)
    model = None
    if kind.local_server:
        from lagrseq.llm.gguf import describe

        settings = local_settings(parse_provider(provider).argument, options)
        model = describe(settings.model, "local")
        if model.header is None:
            raise UsageError(f"local model {settings.model}: {model.problem}")
    answers = Path(answers)
    from lagrseq.paths import check_output, write_output

    check_output(answers, "--answers", replace=False)  # before anything is asked (or paid for)
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
        # an existing file is never overwritten nor appended to (its answers would be screened
        # with these): refused before asking, and again when the file is put in place
        write_output(answers, lambda handle: handle.write("".join(line + "\n" for line in lines)), "--answers", replace=False)
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
        for path in (md, table, png):  # every output checked before the first is written
            outputs.check(path, "--out")
        outputs.write_text(md, "\n".join(markdown(screens)) + "\n", "--out")
        outputs.write_text(table, csv_text(screens), "--out")
        outputs.save_figure(figure(screens), png, "--out", dpi=100, metadata={"Software": None})
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


def temperature_rows(screens: Sequence[Screen], model: Any, tests: Sequence[TemperatureTest] = ()) -> list[tuple[str, str, str, str, str, str]]:
    """The temperature model ``model`` (:class:`lagrseq.tasks.cube.TemperatureModel`) against
    real answers: for each temperature above 0 and prefix length, the accuracy it predicts from
    the same model's tau = 0 answers against the accuracy measured (with its Wilson interval over
    that prefix's answers, independent draws at tau > 0), and whether the prediction lies inside.
    The row over all prefixes gives the count and the verdict of :func:`temperature_tests`
    (``tests``), not an interval over answers that cluster by prefix. Nothing is fitted to the
    tau > 0 answers."""
    rows: list[tuple[str, str, str, str, str, str]] = []
    for name, temps in _by_model_and_temperature(screens):
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
                # the answers cluster by prefix: no interval over all of them as if independent;
                # the model is judged by the likelihood-ratio test per prefix instead
                predicted_mean = predicted_all / measured_n
                test = next((t for t in tests if t.model == name and t.temperature == tau), None)
                rows.append((name, f"{tau:g}", "all prefixes", f"{100 * predicted_mean:.0f}%", f"{measured_k}/{measured_n} = {100 * measured_k / measured_n:.0f}% (clustered by prefix: see the test)", "-" if test is None else test.verdict()))
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


def _target_tag() -> re.Pattern[str]:
    from typing import get_args

    from lagrseq.config import GridTarget

    names = sorted(get_args(GridTarget), key=len, reverse=True)
    return re.compile(r"(?:^|-)target-(" + "|".join(re.escape(n) for n in names) + r")-")


TARGET_TAG = _target_tag()
"""How a screen file of another arrangement target names it: ``screen-sampled-target-plus-MODEL-t0.jsonl``
(read with ``task.target=plus``; a file without the tag is read with the task's default target)."""


def _by_target(files: Sequence[Path]) -> dict[str | None, list[Path]]:
    groups: dict[str | None, list[Path]] = {}
    for path in files:
        found = TARGET_TAG.search(path.name)
        groups.setdefault(found.group(1) if found else None, []).append(path)
    return groups


def report_sections(root: Path | None = None) -> tuple[list[tuple[str, Any, Any]], str]:
    """The sections of the report's "open models" item, as (stem, table, figure or None), and a
    line saying what they were made of (or why there are none). The files are read under
    ``root``; by default under the current directory, else under the source checkout lagrseq was
    installed from (an editable install: ``reproduce`` started in another directory finds them)."""
    root, where = _sections_root(root)
    import pandas as pd

    from lagrseq.running.recording import record_config
    from lagrseq.tasks.cube import AUTHORS_T0

    files = sorted(root.glob(SCREEN_FILES))
    if not files:
        return [], f"open models: not made: no {SCREEN_FILES} {where}: run lagrseq reproduce from a clone of the repository, or copy its recorded_llm/ folder here"
    configs = [record_config(task, "upstream", None, []) for task in SCREEN_TASKS]
    screens = []
    for target, group in sorted(_by_target(files).items(), key=lambda item: item[0] or ""):
        # a grid prompt does not name its target: files of another one say it in their name
        screens += screens_from(group, configs if target is None else [record_config(SCREEN_TASKS[1], "upstream", None, [f"task.target={target}"])])
    data = pd.read_csv(io.StringIO(csv_text(screens)))
    sections = _screen_sections(screens, len(files), data)
    temperature_files = sorted(root.glob(TEMPERATURE_FILES))
    if temperature_files and AUTHORS_T0.temperature is not None:
        sections += _temperature_sections(screens_from(temperature_files, configs[:1]), AUTHORS_T0.temperature)
    return sections, f"open models: {len(files)} recorded answer files, {sum(s.n for s in screens)} answers of {len({s.model for s in screens})} models"


def _sections_root(root: Path | None) -> tuple[Path, str]:
    """The folder the open-model sections are read under, and the words that say where it was looked for."""
    if root is not None:
        return root, f"under {root}"
    from lagrseq.paths import source_checkout

    roots = [Path("."), source_checkout()]
    found = next((where for where in roots if any(where.glob(SCREEN_FILES))), roots[0])
    return found, "here or in a lagrseq source checkout (a non-editable install ships none)"


def _screen_sections(screens: Sequence[Screen], files: int, data: Any) -> list[tuple[str, Any, Any]]:
    """The screen's sections: the models overall (with the figure), per cell, and compared (where any compare)."""
    import pandas as pd

    from lagrseq.analysis.tables import Table

    sections: list[tuple[str, Any, Any]] = [
        (
            "open-models",
            Table(
                f"Open models: screen of {len({s.model for s in screens})} GGUF models at τ = 0 (provenance: open model; {files} recorded answer files, {sum(s.n for s in screens)} answers)",
                OVERALL_COLUMNS,
                tuple(overall_rows(screens)),
                data,
            ),
            figure(screens),
        )
    ]
    cells: list[tuple[str, ...]] = []
    for s in screens:
        cells += [(s.task, s.label(), bin_label(s.task, b, s.size), _percent(s.cells[b][1], s.cells[b][0], interval=not s.from_runs)) for b in sorted(s.cells)]
    sections.append(("open-models-cells", Table("Open models: right answers per prefix length / fill fraction (Wilson 95% interval over the cell's counted answers)", ("task", "model", "shown", "right"), tuple(cells), data), None))
    compared = fisher_rows(screens)
    if compared:
        sections.append(
            (
                "open-models-compare",
                Table(
                    "Open models compared: the model right on most prompts against each other, Fisher's exact test with one unit per prompt in both arms (per task, prompt set and τ)",
                    FISHER_COLUMNS,
                    tuple(compared),
                    pd.DataFrame(compared, columns=["task", "prompt_set", "tau", "best", "best_right", "other", "other_right", "fisher_p", "unshown"]),
                ),
                None,
            )
        )
    return sections


def _temperature_sections(real: Sequence[Screen], model: Any) -> list[tuple[str, Any, Any]]:
    """The temperature sections of ``model`` (the mock's temperature model): its likelihood-ratio test, and its predictions against real τ > 0 answers."""
    import pandas as pd

    from lagrseq.analysis.tables import Table

    tests = temperature_tests(real, model)
    test_table = temperature_test_rows(tests)
    rows = temperature_rows(real, model, tests)
    frame = pd.DataFrame(rows, columns=["model", "tau", "shown", "predicted", "measured", "inside"])
    return [
        (
            "open-models-temperature-test",
            Table(
                f"Open models: the temperature model's likelihood-ratio test per prefix (nothing fitted; parametric bootstrap of {RESAMPLES} draws from the model)",
                TEST_COLUMNS,
                tuple(test_table),
                pd.DataFrame(test_table, columns=["model", "tau", "prefixes", "answers", "G", "df", "p_chi2", "p_bootstrap", "result"]),
            ),
            None,
        ),
        (
            "open-models-temperature",
            Table(
                "Open models: the mock's temperature model (P(right | τ) = P(right | 0) × (1 - τ·drop)) tested on real τ > 0 answers, not refitted",
                ("model", "τ", "shown", "predicted from τ = 0", "measured (Wilson 95% CI over the prefix's answers)", "prediction inside CI (all prefixes: the test)"),
                tuple(rows),
                frame,
            ),
            _with_predictions(figure(real), real, model),
        ),
    ]
