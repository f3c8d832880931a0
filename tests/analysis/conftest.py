"""Small real runs (cube stacking, mock provider) shared by the analysis tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from lagrseq import config as cfg
from lagrseq.running import runner
from lagrseq.study.probe import probe_path, run_accuracy_probe

EPISODES = 20
TRIALS = 3


def make_runs(out: Path, episodes: int = EPISODES, trials: int = TRIALS) -> Path:
    """lagr-seq, lagr and baseline trials (upstream preset) and one accuracy probe under ``out``."""
    for method in ("lagr-seq", "lagr", "baseline"):
        config = cfg.load(
            "cube-stacking", method, "upstream", overrides=[f"run.episodes={episodes}"]
        )
        directory = runner.run_directory(out, config, "mock", 0)
        runner.run_trials(config, trials, 0, "mock", directory)
    probe = cfg.load("cube-stacking", "lagr", "upstream", overrides=["llm.temperature=1.0"])
    run_accuracy_probe(probe, 5, 0, "mock", probe_path(out, probe, "mock", 0, 5))
    return out


@pytest.fixture(scope="session")
def runs_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_runs(tmp_path_factory.mktemp("analysis") / "runs")


@pytest.fixture(scope="session")
def shape() -> tuple[int, int]:
    """(trials, episodes) of every run in ``runs_dir``."""
    return TRIALS, EPISODES
