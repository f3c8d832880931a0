"""A run's identity is everything that can change an answer: the configuration, seed and
provider, the provider's own options (a plugin provider's too, and ``on_miss``), the
distribution of each part (a plugin's version too) and the numerics. A rerun into a folder
whose logs were made with another identity is refused in one line naming what differs, exit 2;
options that cannot change an answer (a budget, a timeout) may change. Every log names the
distribution and version of its task, provider, policy and executor. Real command-line runs
with a throw-away plugin distribution on PYTHONPATH."""

from __future__ import annotations

import json
from pathlib import Path

from lagrseq import __version__
from lagrseq import config as cfg
from lagrseq.llm.options import RecordedOptions
from lagrseq.logs import origins
from lagrseq.logs.reader import read_info
from lagrseq.running import runner
from tests.support.plugins import install_noisy_oracle, lagrseq

SMALL = ("--method", "lagr", "--trials", "1", "--set", "run.episodes=3", "--quiet", "--jobs", "1")


def _oracle_run(site: Path, out: Path, p: str, *extra: str, env: dict[str, str] | None = None) -> tuple[int, str]:
    done = lagrseq(site, "run", "cube-stacking", "--provider", "noisy-oracle", "--oracle-p", p, *extra, *SMALL, "--out", str(out),
                   cwd=out.parent, env=env)
    return done.returncode, done.stderr


def test_resume_with_changed_provider_option_is_refused(tmp_path: Path) -> None:
    site = tmp_path / "site"
    site.mkdir()
    install_noisy_oracle(site)
    out = tmp_path / "runs"
    assert _oracle_run(site, out, "0") == (0, "")
    code, err = _oracle_run(site, out, "1")
    assert code == 2 and err.count("\n") == 1, err
    assert "was made by another run (provider_options.oracle_p: 0.0 -> 1.0)" in err and "Traceback" not in err
    (log,) = out.rglob("trial-000.mcap")
    assert json.loads(read_info(log).run["provider_options"])["oracle_p"] == 0.0  # the first run's log is kept
    code, err = _oracle_run(site, out, "0")  # the same identity resumes
    assert code == 0, err


def test_resume_with_another_plugin_version_is_refused_and_the_log_names_it(tmp_path: Path) -> None:
    site = tmp_path / "site"
    site.mkdir()
    install_noisy_oracle(site, "0.1")
    out = tmp_path / "runs"
    assert _oracle_run(site, out, "0.5") == (0, "")
    (log,) = out.rglob("trial-000.mcap")
    parts = json.loads(read_info(log).run["parts"])
    assert parts["provider"] == {"name": "noisy-oracle", "distribution": "noisy-oracle-plugin", "version": "0.1"}
    builtin = {"distribution": "lagrseq", "version": __version__}
    assert parts["task"] == {"name": "cube-stacking", **builtin} and parts["policy"] == {"name": "always", **builtin}
    assert parts["executor"] == builtin  # its code, not its name: the bytes are the same on every executor
    install_noisy_oracle(site, "0.2")
    code, err = _oracle_run(site, out, "0.5")
    assert code == 2 and err.count("\n") == 1, err
    assert 'parts.provider: "noisy-oracle-plugin 0.1" -> "noisy-oracle-plugin 0.2"' in err


def _mock_log(tmp_path: Path) -> tuple[cfg.ExperimentConfig, Path]:
    config = cfg.load("cube-stacking", "lagr-seq", "upstream", overrides=["run.episodes=2"])
    path = tmp_path / "trial-000.mcap"
    runner.run_one(config, 0, 0, "mock", path)
    return config, path


def test_on_miss_is_part_of_the_identity_and_a_budget_is_not(tmp_path: Path) -> None:
    """The logged options of a log compared with a rerun's: ``on_miss`` differs (refused, both
    values named), a budget or a timeout differs (resumed: it changes no answer)."""
    import dataclasses

    from lagrseq.llm.options import HttpLimits, Limits, LiveOptions

    config, path = _mock_log(tmp_path)
    logged = read_info(path).run["provider_options"]
    refused = runner.option_differences(logged, "recorded:store", RecordedOptions(on_miss="refuse"))
    assert refused == ['provider_options.on_miss: "error" -> "refuse"']
    spend = dataclasses.replace(LiveOptions(), limits=Limits(max_queries=5), http=HttpLimits(read_timeout_s=9.0))
    assert runner.option_differences(logged, "live", spend) == []
    assert runner.option_differences(logged, "live", dataclasses.replace(LiveOptions(), server="llama.cpp")) == [
        'provider_options.server: "openai" -> "llama.cpp"'
    ]
    runner.check_resumable(path, config, 0, "mock", 0)  # the same identity
    assert origins.read_parts(read_info(path).run["parts"])["task"]["distribution"] == "lagrseq"


def test_a_refused_resume_never_prints_the_key(tmp_path: Path) -> None:
    """A plugin option holding the API key (without its ``sk-``) differs: the line names the
    option, the key is blanked in it (and in the log)."""
    site = tmp_path / "site"
    site.mkdir()
    install_noisy_oracle(site)
    secret = "Zq8Xw4Lm2Pv7Rt9Ks3Hd"
    env = {"OPENAI_API_KEY": f"sk-{secret}"}
    out = tmp_path / "runs"
    assert _oracle_run(site, out, "1", "--oracle-label", f"label-{secret}", env=env)[0] == 0
    code, err = _oracle_run(site, out, "1", "--oracle-label", "plain", env=env)
    assert code == 2 and "provider_options.oracle_label:" in err and '-> "plain"' in err, err
    assert secret[:8] not in err and secret[-8:] not in err
    (log,) = out.rglob("trial-000.mcap")
    logged = read_info(log).run["provider_options"]
    assert "oracle_label" in logged and secret[:8] not in logged
