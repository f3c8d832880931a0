"""A trial training alone: the DQN's two backends, paired in one process: the batched backend
(``NetworkGroup.train`` with one request, what ``backend="auto"`` picks) against the reference
(``dqn.Reference``: autograd and ``torch.optim.Adam``).

    PYTHONPATH=. python benchmarks/bench_train_step.py
    PYTHONPATH=. python benchmarks/bench_train_step.py --shape image --steps 1030 --rounds 5

Two networks with the same initial weights train on the same minibatches (drawn from one
replay buffer with one seeded generator each): one as a group of one member, one through the
reference. Rounds alternate which goes first; each round times ``--steps`` steps of each. Prints
ms a step of each, the paired ratio per round and its median, the CPU seconds of building the
first ``torch.optim`` optimizer in the process (its import of ``torch._dynamo``, which the batched
backend skips), and whether the two networks' weights and losses are identical bit for bit at
the end (they must be: a trial's log does not depend on the backend).
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np

SHAPES = {
    # the upstream presets' primary networks: observation size (cursor, 3 + cells), hidden layers,
    # actions, minibatch size (no target network: lagrseq/experiments/TASK/upstream.toml)
    "image": (103, (128, 128), 2, 64),
    "arrangement": (28, (64, 64), 2, 16),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--shape", choices=sorted(SHAPES), default="image")
    parser.add_argument("--steps", type=int, default=1030, help="training steps of each path per round (default 1030)")
    parser.add_argument("--rounds", type=int, default=5, help="alternating rounds (default 5)")
    parser.add_argument("--target-interval", type=int, default=0, help="target network refresh (default 0: none, as upstream)")
    args = parser.parse_args()

    from lagrseq.agents.batched import Member, NetworkGroup
    from lagrseq.agents.dqn import Reference, import_torch, mlp
    from lagrseq.agents.replay import ReplayBuffer

    torch = import_torch()
    torch.set_num_threads(1)
    size, hidden, actions, batch = SHAPES[args.shape]
    sizes = (size, *hidden, actions)
    group = NetworkGroup(torch, sizes, 1e-3, 0.95, args.target_interval, torch.device("cpu"))
    started = time.process_time()
    reference = Reference(torch, mlp(torch, sizes, torch.Generator().manual_seed(0)), 1e-3, 0.95,
                          args.target_interval)
    first_optimizer = time.process_time() - started
    learners: list[Any] = [Member(group, mlp(torch, sizes, torch.Generator().manual_seed(0))), reference]
    buffer = ReplayBuffer(10_000, size)
    data = np.random.default_rng(0)
    for _ in range(5_000):
        buffer.add(data.integers(0, 2, size).astype(np.float32), int(data.integers(actions)), float(data.random()),
                   data.integers(0, 2, size).astype(np.float32), bool(data.random() < 0.05))
    draws = [np.random.default_rng(1), np.random.default_rng(1)]
    losses: list[list[float]] = [[], []]
    seconds: list[list[float]] = [[], []]

    def run(which: int) -> None:
        learner, rng = learners[which], draws[which]
        started = time.process_time()
        for _ in range(args.steps):
            losses[which].append(learner.train(buffer.draw(batch, rng)))
        seconds[which].append(time.process_time() - started)

    for round_ in range(args.rounds):
        for which in ((0, 1) if round_ % 2 == 0 else (1, 0)):
            run(which)
    ms = [[1000 * s / args.steps for s in series] for series in seconds]
    ratios = [b / a for a, b in zip(seconds[0], seconds[1], strict=True)]
    same = losses[0] == losses[1] and all(
        torch.equal(a, b) for a, b in zip(learners[0].parameters(), learners[1].parameters(), strict=True)
    )
    print(f"{args.shape} network {size}-{'-'.join(map(str, hidden))}-{actions}, batch {batch}, "
          f"{args.rounds} rounds x {args.steps} steps each, CPU time, one thread")
    print(f"batched (group of one): {', '.join(f'{m:.3f}' for m in ms[0])} ms a step")
    print(f"reference (autograd):   {', '.join(f'{m:.3f}' for m in ms[1])} ms a step")
    print(f"reference / batched per round: {', '.join(f'{r:.2f}' for r in ratios)}; "
          f"median {statistics.median(ratios):.2f}x")
    print(f"the reference's first torch.optim optimizer in this process: {first_optimizer:.2f} s of CPU "
          "(the batched backend builds none)")
    print(f"after {args.rounds * args.steps} steps each: weights and losses "
          f"{'identical bit for bit' if same else 'DIFFER'}")
    if not same:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
