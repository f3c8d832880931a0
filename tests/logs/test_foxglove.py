"""Foxglove picture views: schemas, message builders, and a round trip through the sink."""

from __future__ import annotations

import base64
import json
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lagrseq.logs import foxglove
from lagrseq.logs.events import View
from lagrseq.logs.reader import ReadStats, read_topics
from lagrseq.logs.sink import McapSink, _encode

X_SHAPE = np.eye(10, dtype=int) | np.fliplr(np.eye(10, dtype=int))
DIAMOND = np.array(
    [[0, 0, 1, 0, 0], [0, 1, 0, 1, 0], [1, 0, 0, 0, 1], [0, 1, 0, 1, 0], [0, 0, 1, 0, 0]]
)


@pytest.mark.parametrize("schema", [foxglove.RAW_IMAGE_SCHEMA, foxglove.GRID_SCHEMA])
def test_schemas_are_valid_json_schemas_with_foxglove_names(schema: dict) -> None:
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["title"] in ("foxglove.RawImage", "foxglove.Grid")
    assert schema["properties"]["data"]["contentEncoding"] == "base64"


def test_raw_image_is_mono8_with_0_and_255() -> None:
    message = foxglove.raw_image(X_SHAPE, log_time=1_500_000_123)
    jsonschema.validate(message, foxglove.RAW_IMAGE_SCHEMA)
    assert (message["width"], message["height"], message["step"]) == (10, 10, 10)
    assert message["encoding"] == "mono8"
    assert message["timestamp"] == {"sec": 1, "nsec": 500_000_123}
    pixels = np.frombuffer(base64.b64decode(message["data"]), dtype=np.uint8).reshape(10, 10)
    assert set(np.unique(pixels)) == {0, 255}
    assert np.array_equal(pixels == 255, X_SHAPE == 1)
    assert np.array_equal(foxglove.decode(message), X_SHAPE)


def test_grid_rows_start_at_the_bottom_so_row_0_shows_on_top() -> None:
    pattern = np.zeros((5, 5), dtype=int)
    pattern[0, 1] = 1  # top row, second column
    message = foxglove.grid(pattern, log_time=7)
    jsonschema.validate(message, foxglove.GRID_SCHEMA)
    cells = np.frombuffer(base64.b64decode(message["data"]), dtype=np.uint8).reshape(5, 5)
    assert cells[4, 1] == 1 and cells.sum() == 1  # last data row = top of the picture
    assert message["fields"] == [{"name": "occupied", "offset": 0, "type": foxglove.UINT8}]
    assert message["cell_size"] == {"x": 0.05, "y": 0.05}
    assert np.array_equal(foxglove.decode(foxglove.grid(DIAMOND, 0)), DIAMOND)


def test_views_need_2d_patterns() -> None:
    with pytest.raises(ValueError, match="2-D"):
        foxglove.raw_image([1, 0, 1], 0)


def test_views_round_trip_through_the_sink_in_transition_chunks(tmp_path: Path) -> None:
    path = tmp_path / "views.mcap"
    topics = foxglove.view_topics(image=True, grid=True)
    # chunk_bytes=0: a chunk per episode, so that each episode's pictures are a chunk replay skips
    with McapSink(path, {"config": "{}"}, extra_topics=topics, chunk_bytes=0) as sink:
        for episode in range(3):
            for step in range(4):
                t = episode * 4 + step
                sink.write(View(foxglove.IMAGE_TOPIC, foxglove.raw_image(X_SHAPE, t), t))
                sink.write(View(foxglove.GRID_TOPIC, foxglove.grid(DIAMOND, t), t))
            sink.write_record("/episode", {"episode": episode}, t)
            sink.flush()
    from mcap.reader import make_reader

    with path.open("rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None
    names = {summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
    assert {"foxglove.RawImage", "foxglove.Grid"} <= names
    for channel in summary.channels.values():
        schema = summary.schemas[channel.schema_id]
        if schema.name.startswith("foxglove."):
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            json.loads(schema.data)

    stats = ReadStats()
    assert len(read_topics(path, ["/episode"], stats)["/episode"]) == 3
    assert stats.chunks_decompressed == 3 and stats.chunks == 6
    views = read_topics(path, [foxglove.IMAGE_TOPIC, foxglove.GRID_TOPIC])
    assert len(views[foxglove.IMAGE_TOPIC]) == 12
    assert all(np.array_equal(foxglove.decode(m), X_SHAPE) for m in views[foxglove.IMAGE_TOPIC])
    assert all(np.array_equal(foxglove.decode(m), DIAMOND) for m in views[foxglove.GRID_TOPIC])


@settings(max_examples=150, deadline=None)
@given(
    st.lists(
        st.tuples(st.integers(0, 3), st.integers(0, 4_000_000_000), st.sampled_from(["int8", "int64", "bool", "float64"]),
                  st.integers(0, 1), st.booleans()),
        min_size=1, max_size=12,
    ),
    st.integers(1, 5),
    st.integers(1, 7),
    st.sampled_from(["image", 'a "quoted"\\ frame/\u00e9']),
)  # fmt: skip
def test_raw_images_give_raw_image_and_its_json_bytes_for_any_steps(steps, rows: int, cols: int, frame_id: str) -> None:
    """The pictures of a trial's steps (the pattern often unchanged from the step before, or
    changed, in any dtype, any values, a shape changed, a transposed view; a frame id JSON
    escapes): each message is raw_image's, and its ready bytes are the sink's own encoding of
    it."""
    images = foxglove.RawImages(frame_id)
    for seed, log_time, dtype, wider, transposed in steps:
        pattern = np.random.default_rng(seed).integers(-1, 3, (rows, cols + wider)).astype(dtype)
        if transposed:
            pattern = pattern.T
        message = images(pattern, log_time)
        expected = foxglove.raw_image(pattern, log_time, frame_id)
        assert message == expected and list(message) == list(expected)
        assert message.json == _encode(expected)


def test_raw_images_refuse_what_raw_image_refuses_and_the_sink_writes_their_bytes(tmp_path: Path) -> None:
    images = foxglove.RawImages()
    with pytest.raises(ValueError, match="2-D pattern"):
        images([1, 0, 1], 0)
    path = tmp_path / "images.mcap"
    with McapSink(path, {"config": "{}"}, extra_topics=foxglove.view_topics(image=True)) as sink:
        for t in range(5):
            sink.write(View(foxglove.IMAGE_TOPIC, images(X_SHAPE if t < 3 else DIAMOND, t), t))
        sink.write_record("/episode", {"episode": 0}, 4)
    views = read_topics(path, [foxglove.IMAGE_TOPIC])[foxglove.IMAGE_TOPIC]
    assert [m for m in views] == [foxglove.raw_image(X_SHAPE if t < 3 else DIAMOND, t) for t in range(5)]
