"""The built-in parts, registered in ``lagrseq.registry``: four tasks, four provider kinds, six
asking policies, two executors. Read once, on the first use of a registry.

A third-party package registers its parts the same way, through entry points (see
``docs/extending.md``). The factories here are lazy references (``module:function``), so this
module imports nothing beyond the configuration: the concrete parts load when a run builds them.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lagrseq import config as cfg
from lagrseq.registry import (
    EXECUTORS,
    POLICIES,
    PROVIDERS,
    TASKS,
    ExecutorSpec,
    Knob,
    PolicySpec,
    ProviderKind,
    TaskSpec,
)


def lazy(target: str) -> Callable[..., Any]:
    """A function calling ``module:attribute``, imported on the first call."""
    module, _, attribute = target.partition(":")

    def call(*args: Any, **kwargs: Any) -> Any:
        return getattr(importlib.import_module(module), attribute)(*args, **kwargs)

    call.__name__ = attribute
    call.__qualname__ = target
    return call


def presets(task: str) -> Path:
    """The packaged preset folder of a built-in task (next to this module: what
    ``importlib.resources.files("lagrseq")`` gives for an installed package, without importing
    ``importlib.resources`` and the ``zipfile`` module it brings)."""
    return Path(__file__).parent / "experiments" / task


WIRING = "lagrseq.running.wiring"
TASK = "lagrseq.builtin_tasks"
"""The built-in tasks' modules: each holds what its spec names, as a plugin's module would."""
GRID_SECONDARY = {"primary": cfg.DQNConfig, "secondary": cfg.NeuralSecondaryConfig}

TASKS.register(
    TaskSpec(
        name="cube-stacking",
        sections={"task": cfg.CubeTaskConfig, "env": cfg.CubeEnvConfig, "primary": cfg.TabularConfig, "secondary": cfg.TabularSecondaryConfig},
        presets=presets("cube-stacking"),
        make_task=lazy(f"{TASK}.cube_stacking:make_task"),
        make_env=lazy(f"{TASK}.cube_stacking:make_env"),
        extrapolator=lazy(f"{TASK}.cube_stacking:extrapolator"),
        profiles=lazy(f"{TASK}.cube_stacking:profiles"),
        state_keys={"upstream-aliased": lazy(f"{TASK}.cube_stacking:upstream_aliased")},
        estimated_tokens=lazy("lagrseq.tasks.estimates:cube_tokens"),
        frontier_preset="paper",
        description="stack cubes in the target order",
    )
)


def grid_task(name: str, task: type, env: type, module: str, **own: Any) -> TaskSpec:
    """A grid task (image completion, object arrangement, the arm): the DQN sections, the grid
    extrapolator and profiles, steering guidance, the grid picture and both solution-scope
    regimes (``lagrseq.builtin_tasks.grid``); ``module`` (in ``lagrseq.builtin_tasks``) holds its
    ``make_task`` and ``make_env``, ``own`` the rest (and overrides any of these)."""
    shared: dict[str, Any] = {
        "make_task": lazy(f"{TASK}.{module}:make_task"),
        "make_env": lazy(f"{TASK}.{module}:make_env"),
        "extrapolator": lazy(f"{TASK}.grid:extrapolator"),
        "profiles": lazy(f"{TASK}.grid:profiles"),
        "guide": lazy(f"{TASK}.grid:steering_guide"),
        "view_topics": lazy(f"{TASK}.grid:view_topics"),
        "views": lazy(f"{TASK}.grid:views"),
        "solution_scopes": ("episode", "trial"),
        "miss_calibration": lazy(f"{TASK}.grid:miss_calibration"),
    }
    return TaskSpec(
        name=name,
        sections={"task": task, "env": env, **GRID_SECONDARY},
        presets=presets(name),
        **{**shared, **own},
    )


TASKS.register(
    grid_task(
        "image-completion", cfg.ImageTaskConfig, cfg.ImageEnvConfig, "image_completion",
        view_topics=lazy(f"{TASK}.image_completion:view_topics"),
        views=lazy(f"{TASK}.image_completion:views"),
        estimated_tokens=lazy("lagrseq.tasks.estimates:image_tokens"),
        description="draw a 10 x 10 image cell by cell",
    )
)
TASKS.register(
    grid_task(
        "object-arrangement", cfg.ArrangementTaskConfig, cfg.ArrangementEnvConfig, "object_arrangement",
        estimated_tokens=lazy("lagrseq.tasks.estimates:arrangement_tokens"),
        description="place objects on a 5 x 5 table",
    )
)
TASKS.register(
    grid_task(
        "arm-arrangement", cfg.ArmTaskConfig, cfg.ArmEnvConfig, "arm_arrangement",
        view_topics=lazy(f"{TASK}.arm_arrangement:view_topics"),
        views=lazy(f"{TASK}.arm_arrangement:views"),
        missing_dependency=lazy(f"{TASK}.arm_arrangement:missing_dependency"),
        renders=True,
        calibration_steps=40,  # a simulated arm step is slow: 40 steps time it within about 10% of 100
        description="object arrangement placed by a simulated or remote UR5e arm (the arm extra)",
    )
)

OPTIONS = "lagrseq.llm.options"
"""The built-in kinds' options dataclasses (``mock`` has none)."""

PROVIDERS.register(
    ProviderKind(
        name="mock",
        usage="mock, mock:PROFILE",
        make=lazy(f"{WIRING}:make_mock"),
        check_spec=lazy(f"{WIRING}:check_mock_spec"),
        source="mock",
        synthetic=True,
        description="the task's rule-based extrapolator (or a calibrated profile of it); offline, free",
    )
)
PROVIDERS.register(
    ProviderKind(
        name="recorded",
        usage="recorded:STORE",
        make=lazy(f"{WIRING}:make_recorded"),
        options=f"{OPTIONS}:RecordedOptions",
        check_spec=lazy(f"{WIRING}:check_recorded_spec"),
        source="recorded",
        replays=True,
        description="answers recorded before (a store directory or a JSONL export); offline",
    )
)
PROVIDERS.register(
    ProviderKind(
        name="live",
        usage="live, live:MODEL",
        make=lazy(f"{WIRING}:make_live_provider"),
        options=f"{OPTIONS}:LiveOptions",
        with_model=lazy(f"{WIRING}:live_model"),
        source="live",
        paid=True,
        records=True,
        description="an OpenAI-compatible server, asked now (--base-url, --api-key-env)",
    )
)
PROVIDERS.register(
    ProviderKind(
        name="local",
        usage="local or local:MODEL.gguf",
        make=lazy(f"{WIRING}:make_local_provider"),
        options=f"{OPTIONS}:LocalOptions",
        with_model=lazy(f"{WIRING}:local_model"),
        check=lazy(f"{WIRING}:check_local"),
        source="live",
        local_server=True,
        records=True,
        description="a llama.cpp server started on this machine for the run (the local-llm extra)",
    )
)

POLICY = "lagrseq.loop.policies"
GATES = ("min_progress", "budget", "budget_scope", "query_cost")
"""What every policy reads: the progress gate, the query budget and the per-query cost (shared
``[secondary]`` fields)."""


def cost(*candidates: str) -> Knob:
    """``query_cost`` as a learning policy's own knob, tuned over ``candidates``."""
    return Knob("query_cost", 0.0, ge=0, le=1e6, candidates=candidates, help="lambda, subtracted from every query reward")


QUERY_REWARD = Knob("query_reward", "binary", choices=("binary", "logistic"), help="binary or the paper's logistic query reward")
LEARNING_RATE = Knob("learning_rate", 0.1, ge=0, le=1, help="the SEQ bandit's step size")
ASK_PROBABILITY = Knob("ask_probability", 0.5, ge=0, le=1, candidates=("0.05", "0.1", "0.25", "0.5"), help="probability of asking when triggered")
THOMPSON_PRIOR = Knob("thompson_prior", (1.0, 1.0), help="Beta(a, b) prior on an answer being accepted")
STALL_STEPS = Knob(
    "stall_steps", 64, ge=1, le=1_000_000, candidates=("16", "64", "256", "1000000"),
    help="decisions without a new best progress of the episode and without a query, after which it asks (1000000: in effect never)",
)
REASK_DECAY = Knob(
    "reask_decay", 0.0, ge=0, le=1,
    help="a pattern whose answer was rejected k times is asked again (where it would ask) with probability reask_decay**k (0: never again)",
)
SHARED = GATES[:3]
ADVANCE_DESIGN_SEEDS = (1, 3, 1_000_004)
"""``advance``'s rule was read from always's logs of seed 1's tuning seed (1000004) and a first
design was evaluated and dropped on seed 1; the value of ``reask_decay`` compared with the default
was chosen from its candidates' logs on seed 3: none of them is evidence for it."""

POLICIES.register(PolicySpec("never", lazy(f"{POLICY}:make_never"), GATES, method="baseline", order=0, description="never ask (the baseline's behaviour)"))
POLICIES.register(PolicySpec("always", lazy(f"{POLICY}:make_always"), GATES, method="lagr", order=1, description="ask whenever triggered (LaGR)"))
POLICIES.register(PolicySpec("seq", lazy(f"{POLICY}:make_seq"), (*SHARED, cost("0", "0.25", "0.5"), QUERY_REWARD, LEARNING_RATE), order=2, description="the paper's SEQ bandit"))
POLICIES.register(PolicySpec("random", lazy(f"{POLICY}:make_random"), (*GATES, ASK_PROBABILITY), order=3, comparator=True, description="ask with probability ask_probability"))
POLICIES.register(PolicySpec("thompson", lazy(f"{POLICY}:make_thompson"), (*SHARED, cost("0", "0.25", "0.5", "1"), THOMPSON_PRIOR, QUERY_REWARD), order=4, description="Thompson sampling over a posterior per context"))
POLICIES.register(PolicySpec("oracle", lazy(f"{POLICY}:make_oracle"), GATES, order=5, peeks=True, description="ask only when the answer would be accepted (a lower bound)"))
POLICIES.register(PolicySpec("advance", lazy(f"{POLICY}:make_advance"), (*GATES, STALL_STEPS, REASK_DECAY), order=6, description="ask where the progress reaches a new best of the episode or has stalled for stall_steps decisions, on a rejected pattern again only with probability reask_decay**k", design_seeds=ADVANCE_DESIGN_SEEDS))

EXECUTORS.register(ExecutorSpec("local", lazy("lagrseq.running.executors:make_local"), runner_pool=True, description="a process pool on this machine (--jobs)"))
EXECUTORS.register(ExecutorSpec("dask", lazy("lagrseq.running.executors:make_dask"), takes_scheduler=True, workers=("Dask worker", "Dask workers"), description="a Dask cluster: a LocalCluster, or --scheduler tcp://HOST:PORT (the dask extra)"))
