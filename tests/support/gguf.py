"""GGUF files built by hand: a length-prefixed string, a key-value pair, a whole header, and the
pairs of a small chat model."""

from __future__ import annotations

import struct


def gguf_string(text: str) -> bytes:
    data = text.encode()
    return struct.pack("<Q", len(data)) + data


def key_value(key: str, kind: int, payload: bytes) -> bytes:
    return gguf_string(key) + struct.pack("<I", kind) + payload


def build(pairs: list[bytes], version: int = 3, tensors: int = 0, extra: bytes = b"\0" * 32) -> bytes:
    return b"GGUF" + struct.pack("<IQQ", version, tensors, len(pairs)) + b"".join(pairs) + extra


def model_pairs(vocabulary: int = 5) -> list[bytes]:
    tokens = struct.pack("<IQ", 8, vocabulary) + b"".join(gguf_string(f"t{i}") for i in range(vocabulary))
    return [
        key_value("general.architecture", 8, gguf_string("qwen2")),
        key_value("general.name", 8, gguf_string("Qwen2.5 0.5B Instruct")),
        key_value("general.basename", 8, gguf_string("Qwen2.5")),
        key_value("general.size_label", 8, gguf_string("0.5B")),
        key_value("general.file_type", 4, struct.pack("<I", 15)),
        key_value("qwen2.context_length", 4, struct.pack("<I", 32768)),
        key_value("qwen2.rope.freq_base", 6, struct.pack("<f", 1e6)),
        key_value("tokenizer.ggml.scores", 9, struct.pack("<IQ", 6, 3) + struct.pack("<3f", 0.0, 1.0, 2.0)),
        key_value("tokenizer.ggml.tokens", 9, tokens),
        key_value("tokenizer.chat_template", 8, gguf_string("{% for m in messages %}{{ m.content }}{% endfor %}")),
        key_value("general.flag", 7, b"\x01"),
    ]
