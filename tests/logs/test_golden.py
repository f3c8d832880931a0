"""The golden log: the log contract and the cube loop's behaviour stay what they were.

Regenerate (only when a change is meant to alter events) with::

    PYTHONPATH=. python -c "from pathlib import Path; from lagrseq import config as c; \\
    from lagrseq.running.runner import run_one; run_one(c.load('cube-stacking', 'lagr-seq', \\
    'upstream', overrides=['run.episodes=4']), 0, 0, 'mock', \\
    Path('fixtures/golden/cube-stacking-lagr-seq-upstream-4ep.mcap'))"
"""

from __future__ import annotations

from pathlib import Path

from lagrseq import config as cfg
from lagrseq.logs.reader import iter_messages, read_info
from lagrseq.running.runner import run_one

GOLDEN = Path(__file__).resolve().parents[2] / "fixtures" / "golden" / "cube-stacking-lagr-seq-upstream-4ep.mcap"


def test_golden_log_is_still_readable() -> None:
    info = read_info(GOLDEN)
    assert info.complete and info.run["method"] == "lagr-seq"
    assert cfg.from_dict(info.config).run.episodes == 4
    topics = {topic for topic, _ in iter_messages(GOLDEN)}
    assert topics == {"/transition", "/query", "/episode"}


def test_todays_code_writes_the_golden_events(tmp_path: Path) -> None:
    """Same events, and every field the golden file has is still there with the same value
    (fields may be added to the contract, never renamed or removed)."""
    config = cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=["run.episodes=4"])
    fresh = run_one(config, 0, 0, "mock", tmp_path / "trial.mcap").path
    old, new = list(iter_messages(GOLDEN)), list(iter_messages(fresh))
    assert [topic for topic, _ in new] == [topic for topic, _ in old]
    for (topic, before), (_, after) in zip(old, new):
        assert {k: after.get(k, "<missing>") for k in before} == before, topic
    golden_config = read_info(GOLDEN).config
    assert cfg.from_dict(golden_config) == cfg.from_dict(read_info(fresh).config)
