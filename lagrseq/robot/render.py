"""Pictures of the arm for people: PNG bytes for the log, PNG frames and a GIF per episode.

``lagrseq run arm-arrangement --render DIR`` attaches an :class:`EpisodeRenderer` to each
trial's env: it writes ``DIR/trial-NNN/episode-EEEE/frame-FFFF.png`` at every reset, at the key
poses of every placement (pick, hover, release, retreat; simulated arm only) and after every
step, and ``DIR/trial-NNN/episode-EEEE.gif`` when the episode ends. Pillow (a dependency of
matplotlib) encodes both.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np

from lagrseq import outputs

GIF_FRAME_MS = 250
"""Time each frame of a GIF is shown."""


def png_bytes(rgb: np.ndarray) -> bytes:
    """An RGB uint8 array as PNG bytes (fast compression: the log compresses again)."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.asarray(rgb, dtype=np.uint8)).save(buffer, format="PNG", compress_level=1)
    return buffer.getvalue()


def write_gif(frames: list[np.ndarray], path: Path, frame_ms: int = GIF_FRAME_MS) -> Path:
    """An animated GIF of RGB frames (looping), written atomically."""
    from PIL import Image

    images = [Image.fromarray(np.asarray(f, dtype=np.uint8)) for f in frames]
    drawn = io.BytesIO()
    images[0].save(drawn, format="GIF", save_all=True, append_images=images[1:], duration=frame_ms, loop=0)
    return outputs.write_bytes(path, drawn.getvalue(), "--render")


class EpisodeRenderer:
    """Writes an arm env's frames as PNG files and each episode as a GIF (``--render DIR``)."""

    def __init__(self, env: Any, directory: Path, size: tuple[int, int] | None = None) -> None:
        self.env = env
        self.directory = Path(directory)
        self.size = size or env.render_size
        self.episode = -1
        self.frames: list[np.ndarray] = []
        self.gifs: list[Path] = []

    def attach(self) -> EpisodeRenderer:
        """Hook into the env (resets and steps) and, for a simulated arm, into its placements."""
        self.directory.mkdir(parents=True, exist_ok=True)
        self.env.recorder = self.record
        robot = self.env.robot
        if hasattr(robot, "on_frame"):
            robot.on_frame = self.record
        return self

    def record(self, moment: str) -> None:
        if moment == "reset":
            self.finish()
            self.episode += 1
        if moment == "close":
            self.finish()
            return
        if self.episode < 0:
            return
        rgb = self.env.robot.render(*self.size)
        if rgb is None:
            return
        folder = self.directory / f"episode-{self.episode:04d}"
        folder.mkdir(exist_ok=True)
        outputs.write_bytes(folder / f"frame-{len(self.frames):04d}-{moment}.png", png_bytes(rgb), "--render")
        self.frames.append(rgb)

    def finish(self) -> None:
        """Write the current episode's GIF (idempotent)."""
        if self.frames:
            self.gifs.append(write_gif(self.frames, self.directory / f"episode-{self.episode:04d}.gif"))
            self.frames = []
