"""Experiment configurations changed for a test."""

from __future__ import annotations

from dataclasses import replace

from lagrseq.config import ExperimentConfig


def with_episodes(config: ExperimentConfig, episodes: int) -> ExperimentConfig:
    """A copy of ``config`` with another episode count."""
    return replace(config, run=replace(config.run, episodes=episodes))
