"""lagrseq frontier: policies run as ordinary runs, the report rebuilt from the logs alone."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from lagrseq import cli
from lagrseq.analysis.frontier import policy_of
from lagrseq.errors import UsageError
from lagrseq.study.frontier import Variant, parse_policies, parse_sweep


def test_policy_items_and_sweeps() -> None:
    variants = parse_policies("never,always,seq,thompson:query_cost=0.5,random:ask_probability=0.1:budget=3,seq")
    assert [v.method for v in variants] == ["baseline", "lagr", "lagr-seq", "lagr-seq", "lagr-seq"]
    assert variants[3].overrides() == ['secondary.policy="thompson"', "secondary.query_cost=0.5"]
    assert variants[4].knobs == (("ask_probability", "0.1"), ("budget", "3"))
    assert parse_sweep("thompson:budget=5:query_cost=0.2,0.4") == [
        Variant("thompson", (("budget", "5"), ("query_cost", "0.2"))),
        Variant("thompson", (("budget", "5"), ("query_cost", "0.4"))),
    ]
    # the progress gate is a knob of any policy, always included (then a lagr-seq run)
    assert parse_sweep("always:min_progress=3,4")[1].overrides() == ['secondary.policy="always"', "secondary.min_progress=4"]
    # a gated row is named by its gate (and is no paper row)
    gated = {"method": "lagr-seq", "secondary": {"policy": "always", "min_progress": 3, "query_cost": 0.5}}
    assert policy_of(gated) == ("always", "cost 0.5 gate 3")
    for bad in ("sometimes", "seq:colour=red", "seq:query_cost", ""):
        with pytest.raises(UsageError):
            parse_policies(bad)
    with pytest.raises(UsageError):
        parse_sweep("thompson")


def test_frontier_runs_policies_and_replay_rebuilds_the_same_table(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "fr"
    args = [
        "frontier", "cube-stacking", "--provider", "mock:authors-t0", "--policies", "never,always,seq,oracle",
        "--sweep", "thompson:query_cost=0,0.5", "--trials", "2", "--set", "run.episodes=6", "--out", str(out), "--quiet",
        "--no-matched-random",
    ]
    assert cli.main(args) == 0
    printed = capsys.readouterr().out
    assert "thompson (cost 0.5)" in printed and "files in" in printed
    report = out / "frontier"
    (csv,) = report.glob("*.csv")
    table = pd.read_csv(csv, keep_default_na=False)
    assert list(table["policy"]) == ["never", "always", "seq", "thompson", "thompson", "oracle"]
    assert dict(zip(table["policy"], table["paper"], strict=False))["seq"] == "SEQ (paper)"
    assert table.loc[table["policy"] == "always", "paper"].item() == "LaGR (paper)"
    assert table.loc[table["policy"] == "never", "queries_mean"].item() == 0
    # the oracle asks only for answers it knows are accepted: at most always's queries
    oracle = table.loc[table["policy"] == "oracle", "queries_mean"].item()
    assert 0 < oracle <= table.loc[table["policy"] == "always", "queries_mean"].item()
    # mock answers carry estimated token usage, priced for gpt-3.5-turbo: dollars grow with queries
    assert table.loc[table["policy"] == "always", "usd_mean"].item() > 0
    assert {p.suffix for p in report.iterdir()} == {".csv", ".md", ".png"}
    # every point ran seed 0, trials 0 and 1: the logs pair them with always (common random numbers)
    judged = table[~table["policy"].isin(["always"])]
    assert set(judged["vs_always_test"]) == {"paired betting bound (log ratio)"}
    # resume: nothing runs again; and the report from the logs alone is byte-identical
    assert cli.main(args) == 0
    again = tmp_path / "again"
    assert cli.main(["frontier", "--replay", str(out), "--out", str(again)]) == 0
    assert (again / csv.name).read_bytes() == csv.read_bytes()
    assert (again / csv.with_suffix(".md").name).read_text() == csv.with_suffix(".md").read_text()


def test_frontier_refuses_a_task_less_run_and_the_oracle_on_live(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["frontier", "--out", str(tmp_path)]) == 2
    assert cli.main(["frontier", "cube-stacking", "--provider", "live", "--policies", "oracle", "--out", str(tmp_path)]) == 2
    assert "oracle" in capsys.readouterr().err


def test_trials_stopped_at_the_first_solve_and_the_full_horizon_group(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--stop-at-first-solve``: every trial ends with its first solved episode and the panel's
    query column says it counts to the first solve; ``--full-horizon-trials K`` adds the variants
    at full length on K trials, a panel (and files) of its own."""
    from lagrseq.logs.reader import read_info, read_topic

    out = tmp_path / "fr"
    args = [
        "frontier", "cube-stacking", "--provider", "mock:authors-t0", "--policies", "always,seq", "--trials", "2",
        "--set", "run.episodes=8", "--out", str(out), "--quiet", "--no-matched-random", "--stop-at-first-solve",
        "--full-horizon-trials", "1",
    ]
    assert cli.main(args) == 0
    printed = capsys.readouterr().out
    stopped = full = shorter = 0
    for log in sorted(out.rglob("*.mcap")):
        episodes = read_topic(log, "/episode")
        if read_info(log).config["run"].get("stop_at", "") == "first_solve":
            stopped += 1
            assert not any(e["solved"] for e in episodes[:-1])  # it ran no episode past its first solve
            assert episodes[-1]["solved"] or len(episodes) == 8
            shorter += len(episodes) < 8
        else:
            full += 1
            assert len(episodes) == 8
    assert (stopped, full) == (4, 2)  # 2 variants x 2 trials stopped, 2 variants x 1 trial at full length
    assert shorter  # guided by the mock's answers, trials solve before their 8th episode
    report = out / "frontier"
    (short,) = report.glob("*first-solve.csv")
    (whole,) = set(report.glob("*.csv")) - {short}
    assert "trials stopped at the first solve" in short.with_suffix(".md").read_text().splitlines()[0]
    assert "queries to the first solve / trial [95% CI]" in short.with_suffix(".md").read_text()
    assert pd.read_csv(whole)["trials"].tolist() == [1, 1] and pd.read_csv(short)["trials"].tolist() == [2, 2]
    assert "trials stopped at the first solve" in printed
    assert cli.main(["frontier", "cube-stacking", "--full-horizon-trials", "2", "--out", str(tmp_path / "x")]) == 2
    assert "--stop-at-first-solve" in capsys.readouterr().err


def test_frontier_help_fits_one_screen_and_leaves_the_protocol_to_the_docs() -> None:
    """Each of the command's own options is one line; the protocol's prose lives in docs/frontier.md."""
    import argparse

    from lagrseq.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices["frontier"]
    shared = {"--provider"}  # the provider's help is every command's
    own = [a for a in sub._actions if a.container.title in ("options", "positional arguments") and a.help
           and not shared & set(a.option_strings)]
    assert len(own) >= 15
    for action in own:
        assert len(str(action.help)) <= 76, action.option_strings
    assert "docs/frontier.md" in str(sub.description) and len(str(sub.description)) < 400
