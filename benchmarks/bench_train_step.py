"""A trial training alone: ``NetworkGroup.train`` with one request against the autograd step it
replaced (issue 35, item 6), paired in one process.

    PYTHONPATH=. python benchmarks/bench_train_step.py
    PYTHONPATH=. python benchmarks/bench_train_step.py --shape image --steps 1030 --rounds 5

Two groups of one member with the same initial weights train on the same minibatches (drawn
from one replay buffer with one seeded generator per group): one through ``train`` (the
no-autograd step every trial now takes), one through the autograd step lagrseq took for a trial
training alone until issue 35 (``functional.linear``, ``mse_loss``, ``torch.autograd.grad``,
fused Adam: kept here as the reference). Rounds alternate which goes first; each round times
``--steps`` steps of each. Prints ms a step of each, the paired ratio per round and its median,
and whether the two groups' weights, Adam moments and losses are identical bit for bit at the
end (they must be: a trial's log does not depend on the path).
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


def autograd_step(group: Any, member: int, batch: Any) -> float:
    """The former ``NetworkGroup._train_one``: one member's step through autograd."""
    from lagrseq.agents.dqn import KERAS_EPSILON, fused_adam_step

    torch, device = group._torch, group.device
    group._stack()
    functional = torch.nn.functional
    parameters, steps, exp_avgs, exp_avg_sqs = group._state(member)

    def forward(tensors: list[Any], x: Any) -> Any:
        for i in range(group.layers):
            x = functional.linear(x, tensors[i], tensors[group.layers + i])
            if i < group.layers - 1:
                x = torch.relu(x)
        return x

    observations = torch.from_numpy(batch.observations).to(device)
    actions = torch.from_numpy(batch.actions).to(device)
    rewards = torch.from_numpy(batch.rewards).to(device)
    with torch.no_grad():
        if group.discount == 0.0:
            targets = rewards
        else:
            bootstrap = group._target_state(member) if group.target_update_interval > 0 else parameters
            following = forward(bootstrap, torch.from_numpy(batch.next_observations).to(device))
            alive = 1.0 - torch.from_numpy(batch.terminals).to(device)
            targets = rewards + group.discount * alive * following.max(dim=1).values
    leaves = [t.detach().requires_grad_() for t in parameters]
    predicted = forward(leaves, observations).gather(1, actions[:, None]).squeeze(1)
    loss = functional.mse_loss(predicted, targets)
    grads = list(torch.autograd.grad(loss, leaves))
    fused_adam_step(torch, parameters, grads, exp_avgs, exp_avg_sqs, steps, group.learning_rate, KERAS_EPSILON,
                    counters=[group._steps[member]])
    group._count(member)
    return float(loss.detach())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--shape", choices=sorted(SHAPES), default="image")
    parser.add_argument("--steps", type=int, default=1030, help="training steps of each path per round (default 1030)")
    parser.add_argument("--rounds", type=int, default=5, help="alternating rounds (default 5)")
    parser.add_argument("--target-interval", type=int, default=0, help="target network refresh (default 0: none, as upstream)")
    args = parser.parse_args()

    from lagrseq.agents.dqn import NetworkGroup, import_torch
    from lagrseq.agents.replay import ReplayBuffer

    torch = import_torch()
    torch.set_num_threads(1)
    size, hidden, actions, batch = SHAPES[args.shape]
    groups = []
    for _ in range(2):
        group = NetworkGroup(torch, (size, *hidden, actions), 1e-3, 0.95, args.target_interval, torch.device("cpu"))
        group.join(torch.Generator().manual_seed(0))
        groups.append(group)
    buffer = ReplayBuffer(10_000, size)
    data = np.random.default_rng(0)
    for _ in range(5_000):
        buffer.add(data.integers(0, 2, size).astype(np.float32), int(data.integers(actions)), float(data.random()),
                   data.integers(0, 2, size).astype(np.float32), bool(data.random() < 0.05))
    draws = [np.random.default_rng(1), np.random.default_rng(1)]
    losses: list[list[float]] = [[], []]
    seconds: list[list[float]] = [[], []]

    def run(which: int) -> None:
        group, rng = groups[which], draws[which]
        started = time.process_time()
        for _ in range(args.steps):
            draw = buffer.draw(batch, rng)
            if which == 0:
                losses[0] += group.train([(0, draw)])
            else:
                losses[1].append(autograd_step(group, 0, draw.batch()))
        seconds[which].append(time.process_time() - started)

    for round_ in range(args.rounds):
        for which in ((0, 1) if round_ % 2 == 0 else (1, 0)):
            run(which)
    ms = [[1000 * s / args.steps for s in series] for series in seconds]
    ratios = [b / a for a, b in zip(seconds[0], seconds[1], strict=True)]
    same = losses[0] == losses[1] and all(
        torch.equal(a, b)
        for a, b in zip(
            [*groups[0].weights, *groups[0].biases, *groups[0].exp_avgs, *groups[0].exp_avg_sqs],
            [*groups[1].weights, *groups[1].biases, *groups[1].exp_avgs, *groups[1].exp_avg_sqs],
            strict=True,
        )
    )
    print(f"{args.shape} network {size}-{'-'.join(map(str, hidden))}-{actions}, batch {batch}, "
          f"{args.rounds} rounds x {args.steps} steps each, CPU time, one thread")
    print(f"train (no autograd): {', '.join(f'{m:.3f}' for m in ms[0])} ms a step")
    print(f"autograd (before):   {', '.join(f'{m:.3f}' for m in ms[1])} ms a step")
    print(f"autograd / train per round: {', '.join(f'{r:.2f}' for r in ratios)}; median {statistics.median(ratios):.2f}x")
    print(f"after {args.rounds * args.steps} steps each: weights, Adam moments and losses "
          f"{'identical bit for bit' if same else 'DIFFER'}")
    if not same:
        raise SystemExit(1)


if __name__ == "__main__":
    main()
