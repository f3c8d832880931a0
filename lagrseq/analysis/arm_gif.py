"""The arm items' animation: a GIF of one episode, made from the camera frames of its log.

Arm-arrangement runs log a ``foxglove.CompressedImage`` (PNG) on ``/view/arm`` every
``env.view_every`` steps (by default every step). :func:`episode_gif` takes the last solved
episode of one trial log (else the last one) and writes its frames as an animated GIF (Pillow,
which matplotlib already needs); when no episode has two frames (frames every 10 steps, 8-step
episodes) it takes the trial's last frames instead, and says which steps the GIF shows.
"""

from __future__ import annotations

import base64
import io
from pathlib import Path

from lagrseq import outputs
from lagrseq.logs.reader import read_topic

ARM_TOPIC = "/view/arm"
LAST_FRAMES = 24
"""Frames shown when the last episode has fewer than two."""
FRAME_MS = 250


def episode_gif(log: str | Path, out: Path) -> str | None:
    """Write the GIF of ``log``'s last solved episode to ``out``; return what it shows (None: the
    log has no camera frames)."""
    from PIL import Image

    frames = read_topic(log, ARM_TOPIC)
    if not frames:
        return None
    episodes = read_topic(log, "/episode")
    steps = [_step(f) for f in frames]
    shown = list(range(len(frames)))
    what = ""
    # the last solved episode (the one that is cut by the step budget shows less), else the last
    candidates = sorted(episodes, key=lambda e: (bool(e.get("solved")), int(e["episode"])), reverse=True)
    for episode in candidates:
        end, length = int(episode["global_step"]), int(episode["length"])
        inside = [k for k, s in enumerate(steps) if end - length <= s < end]
        if len(inside) >= 2:
            shown = inside
            solved = "solved" if episode.get("solved") else "not solved"
            what = f"episode {episode['episode']} ({solved}, steps {end - length}-{end - 1})"
            break
    if not what:
        shown = shown[-LAST_FRAMES:]
        what = f"the trial's last {len(shown)} camera frames (steps {steps[shown[0]]}-{steps[shown[-1]]})"
    images = []
    for k in shown:
        with Image.open(io.BytesIO(base64.b64decode(frames[k]["data"]))) as image:
            images.append(image.convert("RGB"))
    drawn = io.BytesIO()
    images[0].save(drawn, format="GIF", save_all=True, append_images=images[1:], duration=FRAME_MS, loop=0)
    outputs.write_bytes(out, drawn.getvalue(), "--out")
    return f"{what}, {len(images)} frames"


def _step(message: dict) -> int:
    stamp = message.get("timestamp", {})
    return int(stamp.get("sec", 0)) * 1_000_000_000 + int(stamp.get("nsec", 0))
