"""Picture views of grid states for Foxglove: ``foxglove.RawImage`` and ``foxglove.Grid`` (JSON).

Foxglove recognises a channel by its schema *name* (``foxglove.RawImage``, ``foxglove.Grid``) with
schema encoding ``jsonschema`` and message encoding ``json``; bytes fields are base64 strings
(https://docs.foxglove.dev/docs/sdk/schemas, "Custom schema encodings"). The schemas below follow
the Foxglove SDK's ``schemas/jsonschema/RawImage.json`` and ``Grid.json``, trimmed of the long
descriptions.

Use: pass :func:`view_topics` to :class:`~lagrseq.logs.sink.McapSink` (``extra_topics=``) and
write one view per step next to its ``/transition``::

    sink = McapSink(path, metadata, extra_topics=view_topics(image=True))
    sink.write(View(IMAGE_TOPIC, raw_image(pattern, global_step), global_step))

Topics under ``/view`` go into the transition chunks, so replay's tables never decompress them.
Log times are lagrseq's logical clock (one tick per environment step), which Foxglove shows as
nanoseconds; step through the messages rather than playing them back in real time.
"""

from __future__ import annotations

import base64
import json
from typing import Any

import numpy as np

from lagrseq.logs.events import EncodedMessage

IMAGE_TOPIC = "/view/image"
GRID_TOPIC = "/view/grid"

_TIME = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
    },
}

RAW_IMAGE_SCHEMA: dict[str, Any] = {
    "title": "foxglove.RawImage",
    "description": "A raw image",
    "type": "object",
    "properties": {
        "timestamp": {**_TIME, "description": "Timestamp of image"},
        "frame_id": {"type": "string", "description": "Frame of reference for the image"},
        "width": {"type": "integer", "minimum": 0, "description": "Image width in pixels"},
        "height": {"type": "integer", "minimum": 0, "description": "Image height in pixels"},
        "encoding": {"type": "string", "description": "Encoding of the raw image data"},
        "step": {"type": "integer", "minimum": 0, "description": "Byte length of a single row"},
        "data": {"type": "string", "contentEncoding": "base64", "description": "Raw image data"},
    },
}

_VECTOR3 = {
    "title": "foxglove.Vector3",
    "type": "object",
    "properties": {"x": {"type": "number"}, "y": {"type": "number"}, "z": {"type": "number"}},
}
_QUATERNION = {
    "title": "foxglove.Quaternion",
    "type": "object",
    "properties": {
        "x": {"type": "number"},
        "y": {"type": "number"},
        "z": {"type": "number"},
        "w": {"type": "number"},
    },
}

# foxglove.NumericType values used in PackedElementField.type
UINT8 = 1

GRID_SCHEMA: dict[str, Any] = {
    "title": "foxglove.Grid",
    "description": "A 2D grid of data",
    "type": "object",
    "properties": {
        "timestamp": {**_TIME, "description": "Timestamp of grid"},
        "frame_id": {"type": "string", "description": "Frame of reference"},
        "pose": {
            "title": "foxglove.Pose",
            "description": "Origin of grid's corner relative to frame of reference",
            "type": "object",
            "properties": {"position": _VECTOR3, "orientation": _QUATERNION},
        },
        "column_count": {"type": "integer", "minimum": 0, "description": "Number of grid columns"},
        "cell_size": {
            "title": "foxglove.Vector2",
            "description": "Size of single grid cell along x and y axes, relative to `pose`",
            "type": "object",
            "properties": {"x": {"type": "number"}, "y": {"type": "number"}},
        },
        "row_stride": {"type": "integer", "minimum": 0, "description": "Bytes between rows"},
        "cell_stride": {"type": "integer", "minimum": 0, "description": "Bytes between cells"},
        "fields": {
            "type": "array",
            "items": {
                "title": "foxglove.PackedElementField",
                "type": "object",
                "properties": {
                    "name": {"type": "string"},
                    "offset": {"type": "integer", "minimum": 0},
                    "type": {
                        "title": "foxglove.NumericType",
                        "oneOf": [
                            {"title": name, "const": value}
                            for value, name in enumerate(
                                (
                                    "UNKNOWN",
                                    "UINT8",
                                    "INT8",
                                    "UINT16",
                                    "INT16",
                                    "UINT32",
                                    "INT32",
                                    "FLOAT32",
                                    "FLOAT64",
                                )
                            )
                        ],
                    },
                },
            },
            "description": "Fields in `data`",
        },
        "data": {
            "type": "string",
            "contentEncoding": "base64",
            "description": "Grid cell data in row-major (y-major) order, from the bottom-left",
        },
    },
}


def _schema_bytes(schema: dict[str, Any]) -> bytes:
    return json.dumps(schema, sort_keys=True).encode()


def view_topics(image: bool = False, grid: bool = False) -> dict[str, tuple[str, str, bytes]]:
    """``extra_topics`` for :class:`~lagrseq.logs.sink.McapSink`: topic -> (schema name,
    schema encoding, schema data)."""
    topics: dict[str, tuple[str, str, bytes]] = {}
    if image:
        topics[IMAGE_TOPIC] = ("foxglove.RawImage", "jsonschema", _schema_bytes(RAW_IMAGE_SCHEMA))
    if grid:
        topics[GRID_TOPIC] = ("foxglove.Grid", "jsonschema", _schema_bytes(GRID_SCHEMA))
    return topics


def _timestamp(log_time: int) -> dict[str, int]:
    return {"sec": int(log_time) // 1_000_000_000, "nsec": int(log_time) % 1_000_000_000}


def _binary(pattern: Any) -> np.ndarray:
    cells = np.asarray(pattern)
    if cells.ndim != 2:
        raise ValueError(f"a picture view needs a 2-D pattern, found shape {cells.shape}")
    return (cells != 0).astype(np.uint8)


def raw_image(pattern: Any, log_time: int, frame_id: str = "image") -> dict[str, Any]:
    """A ``foxglove.RawImage`` (``mono8``) of a 0/1 grid: on-cells white (255), off black (0).
    Row 0 of the pattern is the top row of the image, as the paper draws it."""
    cells = _binary(pattern)
    height, width = cells.shape
    return {
        "timestamp": _timestamp(log_time),
        "frame_id": frame_id,
        "width": int(width),
        "height": int(height),
        "encoding": "mono8",
        "step": int(width),
        "data": base64.b64encode((cells * 255).tobytes()).decode("ascii"),
    }


_dumps = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode  # as the sink encodes a message


class RawImages:
    """:func:`raw_image` for the steps of one trial, each message with its JSON already encoded
    (:class:`~lagrseq.logs.events.EncodedMessage`: the sink writes the bytes as they are, the
    very bytes it would encode itself). The picture (the base64 data) is made once per distinct
    pattern in a row, and the JSON around it once per shape: a step that leaves the pattern as
    it was costs a comparison of the pattern's bytes and a timestamp, one that changes it the
    base64 of its cells pasted between bytes made before (base64 needs no JSON escaping)."""

    def __init__(self, frame_id: str = "image") -> None:
        self.frame_id = frame_id
        self._key: tuple[Any, ...] | None = None
        self._fields: dict[str, Any] = {}
        self._tail = b""
        self._shape: tuple[int, ...] | None = None
        self._head = b""  # the JSON of the fields up to the data's opening quote, no "{"

    def __call__(self, pattern: Any, log_time: int) -> EncodedMessage:
        cells = pattern if type(pattern) is np.ndarray else np.asarray(pattern)
        key = (cells.shape, cells.dtype.str, cells.tobytes())
        if key != self._key:
            if cells.shape != self._shape:
                fields = raw_image(cells, 0, self.frame_id)  # raises on a pattern that is not 2-D
                del fields["timestamp"]
                fields["data"] = ""
                empty = _dumps(fields).encode()
                if not empty.endswith(b',"data":""}'):  # the data last, as raw_image orders it
                    raise AssertionError(f"unexpected RawImage JSON {empty[-40:]!r}")
                self._head, self._shape = empty[1:-2], cells.shape
                self._fields = fields
            data = base64.b64encode(((cells != 0).view(np.uint8) * np.uint8(255)).tobytes())
            self._fields["data"] = data.decode("ascii")  # each message copies the fields
            self._tail, self._key = b'%b%b"}' % (self._head, data), key
        timestamp = _timestamp(log_time)
        message = EncodedMessage(timestamp=timestamp, **self._fields)
        message.json = b'{"timestamp":{"sec":%d,"nsec":%d},%b' % (timestamp["sec"], timestamp["nsec"], self._tail)
        return message


def grid(
    pattern: Any, log_time: int, cell_size: float = 0.05, frame_id: str = "grid"
) -> dict[str, Any]:
    """A ``foxglove.Grid`` of a 0/1 occupancy grid (one UINT8 field ``occupied``).

    Foxglove fills a grid from its bottom-left corner upwards, so the pattern's rows are written
    last row first: row 0 of the pattern ends up at the top, as the paper draws the arrangement.
    ``cell_size`` defaults to the 5 cm cells of the paper's object-arrangement table."""
    cells = _binary(pattern)[::-1]
    rows, columns = cells.shape
    return {
        "timestamp": _timestamp(log_time),
        "frame_id": frame_id,
        "pose": {
            "position": {"x": 0.0, "y": 0.0, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
        },
        "column_count": int(columns),
        "cell_size": {"x": float(cell_size), "y": float(cell_size)},
        "row_stride": int(columns),
        "cell_stride": 1,
        "fields": [{"name": "occupied", "offset": 0, "type": UINT8}],
        "data": base64.b64encode(np.ascontiguousarray(cells).tobytes()).decode("ascii"),
    }


def decode(message: dict[str, Any]) -> np.ndarray:
    """The 0/1 pattern a view message shows (inverse of :func:`raw_image` and :func:`grid`)."""
    data = np.frombuffer(base64.b64decode(message["data"]), dtype=np.uint8)
    if "encoding" in message:
        return (data.reshape(message["height"], message["step"])[:, : message["width"]] > 0).astype(
            np.uint8
        )
    columns = message["column_count"]
    cells = data.reshape(-1, message["row_stride"])[:, :columns]
    return (cells[::-1] > 0).astype(np.uint8)


# ------------------------------------------------------------------------------------------
# The robot arm: camera frames (foxglove.CompressedImage, PNG) and joint states
# ------------------------------------------------------------------------------------------
ARM_TOPIC = "/view/arm"
JOINTS_TOPIC = "/view/arm/joints"

COMPRESSED_IMAGE_SCHEMA: dict[str, Any] = {
    "title": "foxglove.CompressedImage",
    "description": "A compressed image",
    "type": "object",
    "properties": {
        "timestamp": {**_TIME, "description": "Timestamp of image"},
        "frame_id": {"type": "string", "description": "Frame of reference for the image"},
        "data": {"type": "string", "contentEncoding": "base64", "description": "Compressed image data"},
        "format": {"type": "string", "description": "Image format: jpeg, png or webp"},
    },
}

JOINT_STATE_SCHEMA: dict[str, Any] = {
    "title": "lagrseq.JointState",
    "description": "The arm's joint positions (radians), named as in the URDF (sensor_msgs/JointState's fields)",
    "type": "object",
    "properties": {
        "timestamp": {**_TIME, "description": "Timestamp of the state"},
        "name": {"type": "array", "items": {"type": "string"}},
        "position": {"type": "array", "items": {"type": "number"}},
    },
}


def arm_topics() -> dict[str, tuple[str, str, bytes]]:
    """``extra_topics`` of an arm run: the camera and the joint state."""
    return {
        ARM_TOPIC: ("foxglove.CompressedImage", "jsonschema", _schema_bytes(COMPRESSED_IMAGE_SCHEMA)),
        JOINTS_TOPIC: ("lagrseq.JointState", "jsonschema", _schema_bytes(JOINT_STATE_SCHEMA)),
    }


def compressed_image(png: bytes, log_time: int, frame_id: str = "camera") -> dict[str, Any]:
    """A ``foxglove.CompressedImage`` of PNG bytes."""
    return {
        "timestamp": _timestamp(log_time),
        "frame_id": frame_id,
        "data": base64.b64encode(png).decode("ascii"),
        "format": "png",
    }


def joint_state(names: Any, positions: Any, log_time: int) -> dict[str, Any]:
    """The arm's joint state as JSON (``name`` and ``position`` as in sensor_msgs/JointState)."""
    return {
        "timestamp": _timestamp(log_time),
        "name": [str(n) for n in names],
        "position": [float(q) for q in positions],
    }
