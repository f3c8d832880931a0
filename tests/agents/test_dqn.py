"""The torch DQN: seeded determinism, target network, bandit mode, devices, learning the diamond.

Tests marked ``torch`` need the dqn extra and skip without it; the missing-extra message is
checked without torch.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lagrseq import config as cfg
from lagrseq.errors import UsageError
from lagrseq.logs.reader import read_topic
from lagrseq.running.runner import run_one

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def torch():  # type: ignore[no-untyped-def]
    return pytest.importorskip("torch")


def make(seed: int = 0, **overrides):  # type: ignore[no-untyped-def]
    from lagrseq.agents.dqn import DQN

    settings = dict(
        observation_size=4, n_actions=2, hidden_sizes=(16, 16), learning_rate=1e-2, discount=0.9,
        batch_size=8, buffer_size=100, target_update_interval=0, seed=seed,
        observation_low=np.zeros(4, np.float32), observation_high=np.array([4, 4, 1, 1], np.float32),
    )  # fmt: skip
    settings.update(overrides)
    return DQN(**settings)


def feed(agent, steps: int = 40, seed: int = 0) -> list[float | None]:  # type: ignore[no-untyped-def]
    data = np.random.default_rng(seed)
    replay = np.random.default_rng(seed + 1)
    losses = []
    for _ in range(steps):
        obs = data.integers(0, 2, 4).astype(np.float32)
        nxt = data.integers(0, 2, 4).astype(np.float32)
        agent.remember(obs, int(data.integers(2)), float(data.random()), nxt, bool(data.random() < 0.1))
        losses.append(agent.train_step(replay))
    return losses


def weights(agent) -> list[np.ndarray]:  # type: ignore[no-untyped-def]
    return [p.detach().cpu().numpy().copy() for p in agent.parameters()]


@pytest.mark.torch
def test_same_seed_same_training(torch) -> None:  # type: ignore[no-untyped-def]
    a, b, c = make(0), make(0), make(1)
    assert all(np.array_equal(x, y) for x, y in zip(weights(a), weights(b), strict=True))
    assert not np.array_equal(weights(a)[0], weights(c)[0])
    losses_a, losses_b = feed(a), feed(b)
    assert losses_a == losses_b
    assert losses_a[:7] == [None] * 7 and all(loss is not None for loss in losses_a[7:])
    assert all(np.array_equal(x, y) for x, y in zip(weights(a), weights(b), strict=True))
    assert a.updates == 33


@pytest.mark.torch
def test_target_network_is_refreshed_every_interval(torch) -> None:  # type: ignore[no-untyped-def]
    agent = make(target_update_interval=5)
    assert agent.target_parameters() is not None
    feed(agent, steps=8)  # one update so far: the target still holds the initial weights
    online, target = agent.parameters(), agent.target_parameters()
    assert not all(torch.equal(a, b) for a, b in zip(online, target, strict=True))
    feed(agent, steps=4, seed=5)  # updates 2..5: copied at the 5th
    online, target = agent.parameters(), agent.target_parameters()
    assert agent.updates == 5 and all(torch.equal(a, b) for a, b in zip(online, target, strict=True))
    assert make().target_parameters() is None  # interval 0: bootstrap from the online network


@pytest.mark.torch
def test_observations_are_normalised_with_the_space_bounds(torch) -> None:  # type: ignore[no-untyped-def]
    agent = make()
    agent.remember(np.array([4, 2, 1, 0], np.float32), 1, 0.0, np.array([0, 4, 0, 1], np.float32), False)
    assert agent.buffer.observations[0].tolist() == [1.0, 0.5, 1.0, 0.0]
    assert agent.buffer.next_observations[0].tolist() == [0.0, 1.0, 0.0, 1.0]
    raw = make(observation_low=None, observation_high=None)
    raw.remember(np.array([4, 2, 1, 0], np.float32), 1, 0.0, np.zeros(4, np.float32), False)
    assert raw.buffer.observations[0].tolist() == [4.0, 2.0, 1.0, 0.0]


@pytest.mark.torch
def test_bandit_mode_fits_rewards(torch) -> None:  # type: ignore[no-untyped-def]
    """With discount 0 the network fits Q(s, a) to r: the neural SEQ agent's update."""
    agent = make(observation_low=None, observation_high=None, discount=0.0, batch_size=16)
    good, bad = np.array([1, 1, 0, 0], np.float32), np.array([0, 0, 1, 1], np.float32)
    replay = np.random.default_rng(0)
    for i in range(300):
        state = good if i % 2 else bad
        agent.remember(state, 1, 1.0 if i % 2 else 0.0, state, True)
        agent.remember(state, 0, 0.0, state, True)
        agent.train_step(replay)
    assert agent.q_values(good)[1] == pytest.approx(1.0, abs=0.1)
    assert agent.q_values(bad)[1] == pytest.approx(0.0, abs=0.1)
    assert agent.act(good, 0.0, replay) == 1 and agent.act(bad, 0.0, replay) in (0, 1)


@pytest.mark.torch
def test_epsilon_greedy_draws_from_the_generator_given(torch) -> None:  # type: ignore[no-untyped-def]
    agent = make()
    obs = np.zeros(4, np.float32)
    first = [agent.act(obs, 0.5, generator) for generator in [np.random.default_rng(3)] for _ in range(20)]
    again = [agent.act(obs, 0.5, generator) for generator in [np.random.default_rng(3)] for _ in range(20)]
    assert first == again
    draws = np.random.default_rng(0)
    assert {agent.act(obs, 1.0, draws) for _ in range(50)} == {0, 1}
    greedy = int(agent.q_values(obs).argmax())
    assert all(agent.act(obs, 0.0, draws) == greedy for _ in range(5))


@pytest.mark.torch
def test_devices(torch) -> None:  # type: ignore[no-untyped-def]
    from lagrseq.agents.dqn import resolve_device

    assert resolve_device(torch, "cpu").type == "cpu"
    if torch.cuda.is_available():
        assert resolve_device(torch, "auto").type == "cuda"
        agent = make(device="cuda")
        feed(agent, steps=12)
        assert all(p.is_cuda for p in agent.parameters())
    else:
        assert resolve_device(torch, "auto").type == "cpu"
        with pytest.raises(UsageError, match="sees no CUDA device"):
            make(device="cuda")
    with pytest.raises(UsageError, match="unknown device"):
        resolve_device(torch, "tpu")


def test_missing_torch_names_the_extra() -> None:
    code = (
        "import sys; sys.modules['torch'] = None\n"
        "from lagrseq.agents.dqn import import_torch\n"
        "try:\n    import_torch()\nexcept Exception as exc:\n    print(type(exc).__name__, exc)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, check=True,
        env={"PYTHONPATH": str(REPO), "PATH": ""},
    ).stdout  # fmt: skip
    assert out.startswith("UsageError") and "pip install 'lagrseq[dqn]'" in out


@pytest.mark.torch
def test_dqn_learns_the_diamond_better_than_random(torch, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """2500 steps of the paper's arrangement DQN (seed 0): the episodes of the second half return
    more than those of a uniformly random policy (measured: 0.35 vs 0.25; "always drop", the
    optimum, expects 0.58)."""

    def late_returns(*overrides: str) -> float:
        config = cfg.load("object-arrangement", "baseline", "paper", overrides=["run.max_steps=2500", *overrides])
        result = run_one(config, 0, 0, "mock", tmp_path / f"{len(overrides)}.mcap")
        episodes = read_topic(result.path, "/episode")
        late = [e["return"] for e in episodes if e["global_step"] > 1250 and (e["solved"] or e["length"] == 50)]
        return float(np.mean(late))

    learned = late_returns()
    random = late_returns('primary.epsilon_schedule="constant"')  # epsilon stays 1
    assert learned > random + 0.05


@pytest.mark.torch
def test_fused_adam_is_torch_adam_bit_for_bit(torch) -> None:  # type: ignore[no-untyped-def]
    """lagrseq's Adam step runs the kernel of ``torch.optim.Adam(fused=True)``: equal weights
    after every step (with the Keras epsilon the agents use)."""
    from lagrseq.agents.batched import fused_adam_step
    from lagrseq.agents.dqn import mlp

    def net():  # type: ignore[no-untyped-def]
        return mlp(torch, (5, 32, 32, 3), torch.Generator().manual_seed(7))

    ours, theirs = net(), net()
    parameters = list(ours.parameters())
    steps = [torch.zeros((), dtype=torch.float32) for _ in parameters]
    exp_avgs = [torch.zeros_like(p) for p in parameters]
    exp_avg_sqs = [torch.zeros_like(p) for p in parameters]
    reference = torch.optim.Adam(theirs.parameters(), lr=1e-3, eps=1e-7, fused=True)
    data = torch.Generator().manual_seed(3)
    for _ in range(25):
        x, y = torch.rand(16, 5, generator=data), torch.rand(16, 3, generator=data)
        grads = torch.autograd.grad(torch.nn.functional.mse_loss(ours(x), y), parameters)
        fused_adam_step(torch, parameters, list(grads), exp_avgs, exp_avg_sqs, steps, 1e-3, 1e-7)
        reference.zero_grad(set_to_none=True)
        torch.nn.functional.mse_loss(theirs(x), y).backward()
        reference.step()
        for a, b in zip(ours.parameters(), theirs.parameters(), strict=True):
            assert torch.equal(a, b)


@pytest.mark.torch
def test_building_and_training_an_agent_does_not_import_dynamo(torch) -> None:  # type: ignore[no-untyped-def]
    """Start-up: torch._dynamo (about 2 s of CPU) is not imported by a DQN agent's life."""
    code = (
        "import sys, numpy as np\n"
        "from lagrseq.agents.dqn import DQN\n"
        "agent = DQN(4, 2, (16,), 1e-2, 0.9, 4, 50, 2, 0)\n"
        "rng = np.random.default_rng(0)\n"
        "for _ in range(10):\n"
        "    agent.remember(np.ones(4), 1, 1.0, np.zeros(4), False)\n"
        "    agent.act(np.ones(4), 0.1, rng)\n"
        "    agent.train_step(rng)\n"
        "assert agent.updates == 7, agent.updates\n"
        "print('torch._dynamo' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"


class Given:
    """A minibatch given as arrays, as :meth:`Reference.train` takes a draw from a buffer."""

    def __init__(self, batch) -> None:  # type: ignore[no-untyped-def]
        self._batch = batch

    def batch(self):  # type: ignore[no-untyped-def]
        return self._batch


@pytest.mark.torch
@pytest.mark.parametrize(("sizes", "discount", "interval", "batch_size"), [
    ((103, 128, 128, 2), 0.95, 3, 32),  # the image task's primary network (a short target interval)
    ((100, 128, 128, 2), 0.0, 0, 32),  # its SEQ bandit
    ((50, 64, 64, 2), 0.95, 0, 64),  # arrangement-sized, the released code's batch of 64
])  # fmt: skip
def test_a_group_trains_each_member_as_a_network_of_its_own_bit_for_bit(torch, sizes, discount, interval, batch_size) -> None:  # type: ignore[no-untyped-def]
    """Members of a :class:`NetworkGroup` stepped together, in changing subsets (a member whose
    buffer is not full, a SEQ decision in some trials only), end with exactly the weights,
    target copies, losses and greedy actions of reference networks (``dqn.Reference``) stepped
    alone."""
    everyone = list(range(5))
    check_group_against_networks(torch, sizes, discount, interval, batch_size, 5,
                                 ([everyone, [0, 2, 4], [3], [1, 2], everyone, [4, 0]] * 4)[:20])


@pytest.mark.torch
@pytest.mark.parametrize(("sizes", "discount", "interval", "batch_size"), [
    ((103, 128, 128, 2), 0.95, 3, 32),  # the image task's primary network (a short target interval)
    ((100, 128, 128, 2), 0.0, 0, 24),  # its SEQ bandit, a batch whose mean divides by 24
    ((50, 64, 64, 2), 0.95, 4, 64),  # arrangement-sized
    ((30, 20, 3), 0.95, 2, 8),  # no parameter fills whole vectors of the fused kernel
    ((7, 12, 3), 0.95, 2, 5),  # products of fewer than 400 multiply-adds (bmm loops on its own)
])  # fmt: skip
def test_a_whole_group_steps_at_once_with_each_members_own_numbers(torch, sizes, discount, interval, batch_size) -> None:  # type: ignore[no-untyped-def]
    """Every member stepping at one update count (a lockstep run's primary networks) is one
    fused Adam call over the stacked tensors and one refresh of the stacked target copies;
    after members fall out of step (one skipped a step), each is stepped on its own views.
    Either way each member ends with the numbers of its own reference network stepped alone."""
    everyone = list(range(4))
    check_group_against_networks(torch, sizes, discount, interval, batch_size, 4,
                                 [everyone] * 7 + [[1, 3]] + [everyone] * 4)


def check_group_against_networks(torch, sizes, discount: float, interval: int, batch_size: int, members: int,  # type: ignore[no-untyped-def]
                                 schedule: list[list[int]]) -> None:
    """Step a group's members in the subsets of ``schedule``, one subset a step, and as many
    ``dqn.Reference`` networks (autograd, ``torch.optim.Adam``) alongside; compare after every
    step."""
    from lagrseq.agents.batched import NetworkGroup
    from lagrseq.agents.dqn import Reference, mlp
    from lagrseq.agents.replay import Batch

    torch.set_num_threads(1)
    group = NetworkGroup(torch, sizes, 1e-3, discount, interval, torch.device("cpu"))
    joined = [group.join(mlp(torch, sizes, torch.Generator().manual_seed(seed))) for seed in range(members)]
    assert joined == list(range(members))
    references = [Reference(torch, mlp(torch, sizes, torch.Generator().manual_seed(seed)), 1e-3, discount, interval)
                  for seed in range(members)]
    data = np.random.default_rng(7)
    for subset in schedule:
        chosen = sorted(subset)
        batches = {
            m: Batch(data.random((batch_size, sizes[0]), dtype=np.float32), data.integers(0, sizes[-1], batch_size),
                     data.random(batch_size, dtype=np.float32), data.random((batch_size, sizes[0]), dtype=np.float32),
                     (data.random(batch_size) < 0.2).astype(np.float32))
            for m in chosen
        }  # fmt: skip
        losses = group.train([(m, batches[m]) for m in chosen])
        for m, loss in zip(chosen, losses, strict=True):
            assert loss == references[m].train(Given(batches[m]))  # type: ignore[arg-type]
        assert group.updates == [reference.updates for reference in references]
        for m, reference in enumerate(references):
            assert all(torch.equal(a, b) for a, b in zip(group.parameters(m), reference.parameters(), strict=True))
            if interval:
                assert all(torch.equal(a, b) for a, b in zip(group.parameters(m, target=True), reference.target_parameters(), strict=True))  # type: ignore[arg-type]
            x = torch.from_numpy(data.random(sizes[0], dtype=np.float32))
            assert torch.equal(group.q_values(m, x), reference.q_values(x))


@pytest.mark.torch
@pytest.mark.parametrize("numerics", ["native", "perturbed"])
@pytest.mark.parametrize(("sizes", "discount", "interval", "batch_size"), [
    ((4, 16, 16, 2), 0.9, 0, 8),  # the small network of the tests above
    ((103, 128, 128, 2), 0.95, 3, 32),  # the image task's primary network (a short target interval)
    ((100, 128, 128, 2), 0.0, 0, 32),  # its SEQ bandit
])  # fmt: skip
def test_the_batched_backend_trains_as_the_reference_bit_for_bit(torch, monkeypatch, numerics, sizes, discount,  # type: ignore[no-untyped-def]
                                                                 interval, batch_size) -> None:
    """Two agents of one seed, one per backend, fed the same transitions: the same losses,
    greedy actions, weights and target copies after every step."""
    monkeypatch.setenv("LAGRSEQ_NUMERICS", numerics)
    size = sizes[0]
    agents = [
        make(7, observation_size=size, hidden_sizes=sizes[1:-1], n_actions=sizes[-1], discount=discount,
             target_update_interval=interval, batch_size=batch_size, learning_rate=1e-3,
             observation_low=None, observation_high=None, backend=backend)
        for backend in ("reference", "batched")
    ]  # fmt: skip
    data = np.random.default_rng(3)
    replays = [np.random.default_rng(4), np.random.default_rng(4)]
    for _ in range(batch_size + 30):
        obs, nxt = data.random(size, dtype=np.float32), data.random(size, dtype=np.float32)
        action, reward, terminal = int(data.integers(sizes[-1])), float(data.random()), bool(data.random() < 0.1)
        losses = []
        for agent, replay in zip(agents, replays, strict=True):
            agent.remember(obs, action, reward, nxt, terminal)
            losses.append(agent.train_step(replay))
        assert losses[0] == losses[1]
        probe = data.random(size, dtype=np.float32)
        assert np.array_equal(agents[0].q_values(probe), agents[1].q_values(probe))
    reference, batched = agents
    assert reference.updates == batched.updates == 31
    assert all(torch.equal(a, b) for a, b in zip(reference.parameters(), batched.parameters(), strict=True))
    if interval:
        assert all(torch.equal(a, b) for a, b in zip(reference.target_parameters(), batched.target_parameters(),
                                                     strict=True))


@pytest.mark.torch
def test_an_unknown_backend_is_refused(torch) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(UsageError, match="unknown DQN backend 'fast'; expected one of auto, reference, batched"):
        make(backend="fast")
