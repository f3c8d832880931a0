"""Speed of the robot-arm task (arm-arrangement, simulated UR5e), on one core.

    PYTHONPATH=. python benchmarks/bench_arm.py                  # LaGR-SEQ, paper preset, 1 trial
    PYTHONPATH=. python benchmarks/bench_arm.py --method baseline --trials 2 --placements 400

Prints seconds per placement (and the physics steps it simulates), per episode and per 200-step
trial, and where a trial's time goes: physics (stepSimulation), inverse kinematics (all of it
when the robot is built: every cell's descent is solved once), scene building, camera frames
(/view/arm every env.view_every steps, PNG encoding included), the agents' networks (DQN and
SEQ: acting and training) and the rest (logging, env bookkeeping, the LLM mock). Every number is
measured in this run; nothing is compared with a constant. ARM_NOTES measured 21-28 ms a
placement (about 120 steps) on an idle core.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from lagrseq import config as cfg
from lagrseq.logs.sink import McapSink
from lagrseq.loop.experiment import run_trial
from lagrseq.running import wiring
from lagrseq.running.runner import run_metadata
from lagrseq.tasks.shapes import diamond_cells

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_grids import pin_one_core  # noqa: E402  (the same one-core setup as the grid benchmark)

DIAMOND = diamond_cells(5)  # the arrangement target, placed in its reading order


def placements(count: int) -> None:
    """The robot alone: diamonds placed again and again (cleared after each)."""
    from lagrseq.robot.sim import SimRobot

    started = time.perf_counter()
    robot = SimRobot()
    built = time.perf_counter() - started
    t = robot.timings
    print(f"robot built in {built:.2f} s (scene {t.scene:.2f} s, IK of 25 cells x 11 waypoints + pickup {t.ik:.2f} s)")
    physics0, steps0 = t.physics, t.steps
    started = time.perf_counter()
    done = failed = 0
    while done < count:
        for cell in DIAMOND:
            failed += not robot.place(*cell).ok
            done += 1
        robot.clear()
    seconds = time.perf_counter() - started
    steps = (t.steps - steps0) / done
    print(
        f"placement: {seconds / done * 1000:.1f} ms ({steps:.0f} physics steps, "
        f"{(t.physics - physics0) / done * 1000:.1f} ms of them stepping; {failed} of {done} failed)"
    )
    frame_started = time.perf_counter()
    for _ in range(10):
        robot.render(320, 240)
    print(f"camera frame 320x240: {(time.perf_counter() - frame_started) / 10 * 1000:.1f} ms (TinyRenderer)")
    robot.close()


class Timed:
    """Wraps an agent's methods and adds their time to a counter."""

    def __init__(self, inner: Any, names: tuple[str, ...], clock: dict[str, float]) -> None:
        self.inner, self.clock = inner, clock
        for name in names:
            setattr(self, name, self._wrap(getattr(inner, name)))

    def _wrap(self, method: Any) -> Any:
        def timed(*args: Any, **kwargs: Any) -> Any:
            started = time.perf_counter()
            try:
                return method(*args, **kwargs)
            finally:
                self.clock["networks"] += time.perf_counter() - started

        return timed


def trial(method: str, preset: str, trial_number: int, out: Path) -> None:
    config = cfg.load("arm-arrangement", method, preset, overrides=["run.max_steps=200"])
    clock = {"networks": 0.0}
    started, cpu = time.perf_counter(), time.process_time()
    path = out / f"{method}-{trial_number}.mcap"

    def open_sink() -> McapSink:
        return McapSink(path, run_metadata(config, trial_number, 0, "mock"), extra_topics=wiring.view_topics(config))

    parts = wiring.trial_parts(config, trial_number, 0, "mock", open_sink)
    robot = parts.env.unwrapped.robot
    from dataclasses import replace

    primary = Timed(parts.primary, ("act", "learn"), clock)
    secondary = Timed(parts.secondary, ("decide", "update"), clock) if parts.secondary is not None else None
    parts = replace(parts, primary=primary, secondary=secondary)  # type: ignore[arg-type]
    png_before = robot.timings.render
    result = run_trial(parts, path)
    total, cpu = time.perf_counter() - started, time.process_time() - cpu
    t = robot.timings
    shares = {
        "physics": t.physics,
        "IK": t.ik,
        "scene": t.scene,
        "camera": t.render - png_before,
        "networks": clock["networks"],
    }
    shares["rest"] = total - sum(shares.values())
    line = ", ".join(f"{k} {v:.2f} s ({v / total:.0%})" for k, v in shares.items())
    episodes = max(result.episodes, 1)
    print(
        f"{method} trial {trial_number}: {total:.1f} s ({cpu:.1f} s of CPU: the rest is waiting for a shared core) "
        f"for {result.steps} steps, {result.episodes} episodes "
        f"({total / episodes:.2f} s per episode), {t.placements} placements ({t.placements / max(result.steps, 1):.0%} of steps)"
    )
    print(f"  where it went (wall clock): {line}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--method", choices=["baseline", "lagr", "lagr-seq"], default="lagr-seq")
    parser.add_argument("--preset", choices=["upstream", "paper"], default="paper")
    parser.add_argument("--trials", type=int, default=1)
    parser.add_argument("--placements", type=int, default=200)
    args = parser.parse_args(argv)
    try:
        import pybullet  # noqa: F401
        import torch  # noqa: F401
    except ImportError as exc:
        print(f"bench_arm needs the arm and dqn extras: {exc}", file=sys.stderr)
        return 2
    print(f"arm-arrangement, one core ({pin_one_core()})")
    placements(args.placements)
    with tempfile.TemporaryDirectory(prefix="lagrseq-bench-arm-") as scratch:
        for k in range(args.trials):
            trial(args.method, args.preset, k, Path(scratch))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
