"""The golden log: the log contract and the cube loop's behaviour stay what they were.

Regenerate (only when a change is meant to alter events) with::

    PYTHONPATH=. python -c "from pathlib import Path; from lagrseq import config as c; \\
    from lagrseq.experiment import run_trial; run_trial(c.load('cube-stacking', 'lagr-seq', \\
    'upstream', overrides=['run.episodes=4']), 0, 0, 'mock', \\
    Path('fixtures/golden/cube-stacking-lagr-seq-upstream-4ep.mcap'))"
"""

from __future__ import annotations

from pathlib import Path

from lagrseq import config as cfg
from lagrseq.experiment import run_trial
from lagrseq.logs.reader import iter_messages, read_info

GOLDEN = Path(__file__).resolve().parents[2] / "fixtures" / "golden" / "cube-stacking-lagr-seq-upstream-4ep.mcap"


def test_golden_log_is_still_readable() -> None:
    info = read_info(GOLDEN)
    assert info.complete and info.run["method"] == "lagr-seq"
    assert cfg.from_dict(info.config).run.episodes == 4
    topics = {topic for topic, _ in iter_messages(GOLDEN)}
    assert topics == {"/transition", "/query", "/episode"}


def test_todays_code_writes_the_golden_events(tmp_path: Path) -> None:
    config = cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=["run.episodes=4"])
    fresh = run_trial(config, 0, 0, "mock", tmp_path / "trial.mcap").path
    assert list(iter_messages(fresh)) == list(iter_messages(GOLDEN))
    assert read_info(fresh).config == read_info(GOLDEN).config
