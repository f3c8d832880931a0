"""The arm items' animation: a GIF of one episode, made from the camera frames of its log.

Arm-arrangement runs log a ``foxglove.CompressedImage`` (PNG) on ``/view/arm`` every
``env.view_every`` steps. :func:`episode_gif` takes the last episode of one trial log and writes
its frames as an animated GIF (Pillow, which matplotlib already needs); when that episode has
fewer than two frames (frames every 10 steps, an 8-step episode) it takes the trial's last
frames instead, and says which steps the GIF shows.
"""

from __future__ import annotations

import base64
import io
from pathlib import Path

from lagrseq.logs.reader import read_topic

ARM_TOPIC = "/view/arm"
LAST_FRAMES = 24
"""Frames shown when the last episode has fewer than two."""
FRAME_MS = 250


def episode_gif(log: str | Path, out: Path) -> str | None:
    """Write the GIF of ``log``'s last episode to ``out``; return what it shows (None: the log
    has no camera frames)."""
    from PIL import Image

    frames = read_topic(log, ARM_TOPIC)
    if not frames:
        return None
    episodes = read_topic(log, "/episode")
    steps = [_step(f) for f in frames]
    shown = list(range(len(frames)))
    what = ""
    if episodes:
        last = episodes[-1]
        end, length = int(last["global_step"]), int(last["length"])
        inside = [k for k, s in enumerate(steps) if end - length <= s < end]
        if len(inside) >= 2:
            shown = inside
            what = f"episode {last['episode']} (steps {end - length}-{end - 1})"
    if not what:
        shown = shown[-LAST_FRAMES:]
        what = f"the trial's last {len(shown)} camera frames (steps {steps[shown[0]]}-{steps[shown[-1]]})"
    images = []
    for k in shown:
        with Image.open(io.BytesIO(base64.b64decode(frames[k]["data"]))) as image:
            images.append(image.convert("RGB"))
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(out.name + ".partial")
    images[0].save(partial, format="GIF", save_all=True, append_images=images[1:], duration=FRAME_MS, loop=0)
    partial.replace(out)
    return f"{what}, {len(images)} frames"


def _step(message: dict) -> int:
    stamp = message.get("timestamp", {})
    return int(stamp.get("sec", 0)) * 1_000_000_000 + int(stamp.get("nsec", 0))
