"""Fig. 4 of the paper: the LLM alone, no RL. Every prefix of the target is shown to the provider
``samples`` times; each answer is logged as a ``/query`` record, and replay rebuilds the accuracy
curves from these records alone."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import msgspec

from lagrseq import seeding
from lagrseq.config import ExperimentConfig
from lagrseq.errors import UsageError
from lagrseq.logs.events import ProbeQueryEvent, QueryEvent
from lagrseq.logs.schemas import ACCURACY_METHOD
from lagrseq.logs.sink import McapSink, NullSink
from lagrseq.loop.experiment import TrialResult, query_event
from lagrseq.loop.lagr import consult
from lagrseq.running.wiring import make_provider, make_task
from lagrseq.seeding import Stream
from lagrseq.tasks import cube


def run_accuracy_probe(
    config: ExperimentConfig,
    samples: int,
    seed: int,
    provider_spec: str,
    path: Path,
    log: bool = True,
    provider_options: Any = None,
) -> TrialResult:
    """Query the provider ``samples`` times with every prefix of the target (1/N to N/N of the
    sequence) and log each answer as a ``/query`` record with ``prefix_length`` and ``fraction``
    (= prefix length / N). ``provider_options``: the provider kind's (None: its defaults), logged
    with the run; a store's ``on_miss`` applies here as in a trial (the prefixes are fixed, so a
    miss is a prefix nobody recorded: a refused one counts as a wrong answer, source ``miss``)."""
    from lagrseq.running.runner import run_metadata

    started = time.perf_counter()
    task = make_task(config)
    if not isinstance(task, cube.CubeStacking):
        raise UsageError(f"the accuracy probe needs a sequence task (cube-stacking), not {config.task.name!r}")
    provider = make_provider(provider_spec, config, seeding.generator(seed, 0, Stream.LLM), provider_options)
    metadata = {**run_metadata(config, 0, seed, provider_spec, provider_options), "method": ACCURACY_METHOD}
    metadata["samples"] = str(samples)
    # A recorded store's answers are drawn without replacement (each recorded answer once per
    # prefix before any repeats): the probe measures the accuracy of what was recorded, and
    # resampling 10 recorded answers with replacement would show, say, 3/10 where 5/10 are right.
    draw = getattr(provider, "draw_without_replacement", None)
    if draw is not None:
        draw()
        metadata["recorded_draws"] = "without replacement up to the samples each prompt holds"
    # a chunk per prefix (chunk_bytes=0): a crash keeps every finished prefix, live answers included
    sink: McapSink | NullSink = McapSink(path, metadata, chunk_bytes=0) if log else NullSink()
    target = task.target
    index = 0
    with sink, provider:  # type: ignore[attr-defined]
        for length in range(1, len(target) + 1):
            prefix = tuple(target[:length])
            for sample in range(samples):
                result = consult(task, provider, config.llm, config.lagr.threshold, prefix)
                decision = QueryEvent(0, 0, sample, index, prefix, 1)
                event = query_event(decision, result, provider.name, config.llm.temperature, 0.0)
                fields = msgspec.structs.asdict(event)
                sink.write(ProbeQueryEvent(**fields, prefix_length=length, fraction=length / len(target)))
                index += 1
            sink.flush()
    return TrialResult(path, 0, 0, 0, index, 0.0, time.perf_counter() - started)


def probe_path(out: Path, config: ExperimentConfig, provider_spec: str, seed: int, samples: int) -> Path:
    """``OUT/<task>/llm-accuracy/<preset>-<provider>-seed<S>-<digest>/samples-<K>.mcap``."""
    from lagrseq.running.runner import provider_slug

    name = f"{config.preset}-{provider_slug(provider_spec)}-seed{seed}-{config.digest()}"
    return out / config.task.name / ACCURACY_METHOD / name / f"samples-{samples:04d}.mcap"
