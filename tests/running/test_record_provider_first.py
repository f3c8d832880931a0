"""``lagrseq record`` with a provider it cannot ask says so first, before anything about its
prompts or its runs (a task without a default prompt set, a missing --from-runs folder)."""

from __future__ import annotations

from pathlib import Path

import pytest

from lagrseq import cli


@pytest.mark.parametrize(
    "extra",
    [
        ["image-completion"],  # no default prompt set: once said before the provider
        ["cube-stacking", "--from-runs", "no-such-folder"],
    ],
)
def test_record_names_a_provider_it_cannot_ask_before_its_prompts(tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str]) -> None:
    for provider in ("mock", "recorded:store"):
        code = cli.main(["record", *extra, "--provider", provider, "--store", str(tmp_path / "store")])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1, err
        assert f"lagrseq record asks a live or local model, not {provider!r}" in err
    assert not (tmp_path / "store").exists()
