"""A deep Q-network in torch (the ``dqn`` extra): the primary agent of the grid tasks and, with
discount 0, the neural SEQ bandit.

This is the only module of lagrseq that imports torch, and it does so when an agent is built, so
everything else works without the extra. What it does, per environment step (Mnih et al. 2015,
with the paper's hyperparameter table):

- act: epsilon-greedy on Q(s, .) of the online network (ties go to the first action);
- remember the transition in a :class:`~lagrseq.agents.replay.ReplayBuffer` (normalised
  observations, float32);
- once the buffer holds a batch, one Adam step on the MSE between Q(s, a) and
  r + discount * max_a' Q_target(s', a') (r alone at terminal transitions) for one minibatch drawn
  with the generator passed in (:meth:`Reference.train`, as CleanRL's ``dqn.py`` writes it). The
  released code instead fits every sample of its minibatch separately (64 single-sample Keras
  steps per environment step, SPEC 2.2); lagrseq does not.
- Q_target is a copy of the online network refreshed every ``target_update_interval`` optimiser
  steps, or the online network itself when the interval is 0 (released code: no target network).

Weights start as Keras' defaults do in the released code (Glorot-uniform, zero biases), drawn from
a torch generator seeded once per agent from the trial seed; Adam uses Keras' epsilon (1e-7).
Under ``LAGRSEQ_NUMERICS=perturbed`` (:mod:`lagrseq.agents.numerics`: another CPU, simulated)
the initial parameters are one ulp higher and each minibatch's rows are summed in reverse order.

Two backends compute the update, with the same numbers bit for bit (tests/agents/test_dqn.py):
:class:`Reference` (autograd and ``torch.optim.Adam``: the one to read) and the seed-batched
:mod:`lagrseq.agents.batched`, which stacks the networks of one shape so that the trials of a
lockstep run (:mod:`lagrseq.agents.lockstep`) train in one call per step. ``backend="auto"``
(what runs use) picks the batched one: it batches lockstep trials, and a trial training alone
takes fewer CPU seconds per step with it and skips torch.optim's import of torch._dynamo
(``benchmarks/bench_train_step.py`` prints both).
"""

from __future__ import annotations

import copy
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from lagrseq.agents import batched, lockstep, numerics
from lagrseq.agents.batched import KERAS_EPSILON
from lagrseq.agents.replay import Draw, ReplayBuffer
from lagrseq.errors import UsageError

DEVICES = ("cpu", "cuda", "auto")


def import_torch() -> Any:
    """torch, or a one-line error naming the extra that provides it."""
    try:
        import torch
    except ImportError:
        raise UsageError(
            "the DQN agents need torch, which is not installed; install the extra with "
            "pip install 'lagrseq[dqn]'"
        ) from None
    return torch


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the OS has one)."""
    affinity = getattr(os, "sched_getaffinity", None)
    return max(1, len(affinity(0)) if affinity is not None else (os.cpu_count() or 1))


def resolve_device(torch: Any, requested: str) -> Any:
    """``cpu``; ``cuda`` (an error if torch sees no GPU); ``auto``: cuda when available, else cpu."""
    if requested == "cpu":
        return torch.device("cpu")
    available = bool(torch.cuda.is_available())
    if requested == "auto":
        return torch.device("cuda" if available else "cpu")
    if requested == "cuda":
        if not available:
            raise UsageError(
                f"device 'cuda' was asked for but torch {torch.__version__} sees no CUDA device; "
                "set the agent's device to \"cpu\" or \"auto\", or install a CUDA build of torch"
            )
        return torch.device("cuda")
    raise UsageError(f"unknown device {requested!r}; expected one of {', '.join(DEVICES)}")


def mlp(torch: Any, sizes: Sequence[int], generator: Any) -> Any:
    """Linear layers of the given widths with ReLU between them and a linear output."""
    layers: list[Any] = []
    for i, (fan_in, fan_out) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        linear = torch.nn.Linear(fan_in, fan_out)
        torch.nn.init.xavier_uniform_(linear.weight, generator=generator)
        torch.nn.init.zeros_(linear.bias)
        numerics.perturb(torch, [linear.weight, linear.bias])  # LAGRSEQ_NUMERICS=perturbed: one ulp up
        layers.append(linear)
        if i < len(sizes) - 2:
            layers.append(torch.nn.ReLU())
    return torch.nn.Sequential(*layers)



class Reference:
    """One Q-network trained as CleanRL's ``dqn.py`` trains it: autograd, ``mse_loss``,
    ``zero_grad``, ``backward``, Adam's ``step`` (``fused=True``: the kernel the batched backend
    runs, so both give the same bits)."""

    def __init__(self, torch: Any, network: Any, learning_rate: float, discount: float,
                 target_update_interval: int) -> None:
        self._torch = torch
        self.q_network = network
        self.target_network = copy.deepcopy(network).requires_grad_(False) if target_update_interval > 0 else None
        self.optimizer = torch.optim.Adam(network.parameters(), lr=learning_rate, eps=KERAS_EPSILON, fused=True)
        self.discount = discount
        self.target_update_interval = target_update_interval
        self.updates = 0

    def parameters(self) -> list[Any]:
        return list(self.q_network.parameters())

    def target_parameters(self) -> list[Any] | None:
        return None if self.target_network is None else list(self.target_network.parameters())

    def q_values(self, x: Any) -> Any:
        with self._torch.no_grad():
            return self.q_network(x[None])[0]

    def train(self, draw: Draw) -> float:
        """One Adam step on the minibatch; returns its loss before the step."""
        torch = self._torch
        device = self.parameters()[0].device
        observations, actions, rewards, next_observations, terminals = (
            torch.from_numpy(column).to(device) for column in draw.batch()
        )
        with torch.no_grad():
            if self.discount == 0.0:  # a bandit (SEQ): every decision ends
                td_target = rewards
            else:
                target_max = (self.target_network or self.q_network)(next_observations).max(dim=1).values
                td_target = rewards + self.discount * (1.0 - terminals) * target_max
        predicted = self.q_network(observations).gather(1, actions[:, None]).squeeze(1)
        loss = torch.nn.functional.mse_loss(predicted, td_target)
        self.optimizer.zero_grad()
        loss.backward()
        self.optimizer.step()
        self.updates += 1
        if self.target_network is not None and self.updates % self.target_update_interval == 0:
            self.target_network.load_state_dict(self.q_network.state_dict())
        return float(loss.item())


BACKENDS = ("auto", "reference", "batched")


class DQN:
    """Q-learning with a multilayer perceptron, a replay buffer and an optional target network.

    ``backend``: ``reference`` (:class:`Reference`), ``batched`` (the network is a member of a
    :class:`~lagrseq.agents.batched.NetworkGroup`, shared by the trials' agents of one shape in a
    lockstep run) or ``auto`` (batched: see the module's docstring). Both give the same numbers."""

    def __init__(
        self,
        observation_size: int,
        n_actions: int,
        hidden_sizes: Sequence[int],
        learning_rate: float,
        discount: float,
        batch_size: int,
        buffer_size: int,
        target_update_interval: int,
        seed: int,
        device: str = "cpu",
        observation_low: np.ndarray | None = None,
        observation_high: np.ndarray | None = None,
        cpu_threads: int = 0,
        backend: str = "auto",
    ) -> None:
        if backend not in BACKENDS:
            raise UsageError(f"unknown DQN backend {backend!r}; expected one of {', '.join(BACKENDS)}")
        torch = import_torch()
        self._torch = torch
        threads = 0
        if cpu_threads > 0:
            # never more threads than cores this process may use: 1024 threads on 2 cores made
            # every update 65 times slower (1.9 against 121 updates/s measured)
            threads = min(cpu_threads, usable_cores())
            torch.set_num_threads(threads)
        self.device = resolve_device(torch, device)
        self.n_actions = n_actions
        self.batch_size = batch_size
        sizes = (observation_size, *hidden_sizes, n_actions)
        network = mlp(torch, sizes, torch.Generator().manual_seed(int(seed))).to(self.device)
        self.learner: Reference | batched.Member
        if backend == "reference":
            self.learner = Reference(torch, network, learning_rate, discount, target_update_interval)
        else:
            # trials of different runs may meet in one conductor: only networks whose batched calls
            # fit together (shapes, minibatch size, hyperparameters, device, threads) share a group
            key = ("dqn", sizes, batch_size, learning_rate, discount, target_update_interval, str(self.device), threads)

            def make() -> batched.NetworkGroup:
                return batched.NetworkGroup(torch, sizes, learning_rate, discount, target_update_interval, self.device)

            conductor = lockstep.current()
            group = make() if conductor is None else conductor.shared(key, make)
            group.threads = threads
            self.learner = batched.Member(group, network)
        self.buffer = ReplayBuffer(buffer_size, observation_size)
        self._perturbed = numerics.numerics() == numerics.PERTURBED
        # Normalisation to [0, 1] with the observation space's bounds (None: raw observations).
        self._low: np.ndarray | None = None
        self._scale: np.ndarray | None = None
        if observation_low is not None and observation_high is not None:
            low = np.asarray(observation_low, dtype=np.float32)
            span = np.asarray(observation_high, dtype=np.float32) - low
            self._low = low
            self._scale = np.where(span > 0, 1.0 / np.where(span > 0, span, 1.0), 1.0).astype(np.float32)

    @property
    def updates(self) -> int:
        """Optimiser steps taken so far."""
        return self.learner.updates

    def parameters(self) -> list[Any]:
        """The online network's weights and biases, layer by layer (``nn.Linear``'s shapes)."""
        return self.learner.parameters()

    def target_parameters(self) -> list[Any] | None:
        """The target network's, or None without one (bootstrap from the online network)."""
        return self.learner.target_parameters()

    # ------------------------------------------------------------------ acting
    def normalise(self, observation: np.ndarray) -> np.ndarray:
        x = np.asarray(observation, dtype=np.float32)
        if self._scale is None or self._low is None:
            return x
        return (x - self._low) * self._scale

    def q_values(self, observation: np.ndarray) -> np.ndarray:
        """Q(s, .) of the online network for one observation."""
        x = self._torch.from_numpy(self.normalise(observation)).to(self.device)
        return self.learner.q_values(x).cpu().numpy()  # type: ignore[no-any-return]

    def act(self, observation: np.ndarray, epsilon: float, rng: np.random.Generator) -> int:
        """epsilon-greedy: a uniform action with probability epsilon, else the first argmax."""
        if rng.random() < epsilon:
            return int(rng.integers(self.n_actions))
        return int(self.q_values(observation).argmax())

    # ------------------------------------------------------------------ learning
    def remember(
        self,
        observation: np.ndarray,
        action: int,
        reward: float,
        next_observation: np.ndarray,
        terminal: bool,
    ) -> None:
        self.buffer.add(
            self.normalise(observation), action, reward, self.normalise(next_observation), terminal
        )

    def train_step(self, rng: np.random.Generator) -> float | None:
        """One Adam step on a minibatch drawn with ``rng``; None until the buffer holds a batch.
        Returns the minibatch's loss before the step. In a lockstep run the step is taken
        together with the other trials' (:func:`lagrseq.agents.lockstep.request`)."""
        if len(self.buffer) < self.batch_size:
            return None
        draw = self.buffer.draw(self.batch_size, rng)
        if self._perturbed:  # another machine, simulated: the same minibatch, summed in the other order
            draw = Draw(self.buffer, numerics.reorder(draw.index))
        return self.learner.train(draw)
