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
  with the generator passed in. The released code instead fits every sample of its minibatch
  separately (64 single-sample Keras steps per environment step, SPEC 2.2); lagrseq does not.
- Q_target is a copy of the online network refreshed every ``target_update_interval`` optimiser
  steps, or the online network itself when the interval is 0 (released code: no target network).

Weights start as Keras' defaults do in the released code (Glorot-uniform, zero biases), drawn from
a torch generator seeded once per agent from the trial seed; Adam uses Keras' epsilon (1e-7).
"""

from __future__ import annotations

import copy
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from lagrseq.agents.replay import ReplayBuffer
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
        layers.append(linear)
        if i < len(sizes) - 2:
            layers.append(torch.nn.ReLU())
    return torch.nn.Sequential(*layers)


class FusedAdam:
    """Adam (Kingma and Ba; torch's defaults: betas 0.9 and 0.999, no weight decay) as one call
    of torch's fused kernel per step, the kernel ``torch.optim.Adam(..., fused=True)`` runs: the
    same numbers bit for bit (tests/agents/test_dqn.py), without ``torch.optim``'s machinery.

    Why not ``torch.optim.Adam`` itself: constructing any ``torch.optim`` optimizer imports
    ``torch._dynamo`` (its ``add_param_group`` is wrapped in ``torch._disable_dynamo``), 1.6 to
    2.2 s of CPU in every process that builds an agent, for a compiler lagrseq never uses.
    """

    def __init__(self, torch: Any, parameters: Sequence[Any], lr: float, eps: float,
                 betas: tuple[float, float] = (0.9, 0.999)) -> None:
        self._torch = torch
        self.parameters = list(parameters)
        self.lr, self.eps, self.betas = lr, eps, betas
        # Per parameter, as torch keeps them for fused=True: a float32 step count on the
        # parameter's device and the two moment estimates.
        self.steps = [torch.zeros((), dtype=torch.float32, device=p.device) for p in self.parameters]
        self.exp_avgs = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.parameters]
        self.exp_avg_sqs = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.parameters]

    def zero_grad(self, set_to_none: bool = True) -> None:
        for parameter in self.parameters:
            if set_to_none:
                parameter.grad = None
            elif parameter.grad is not None:
                parameter.grad.zero_()

    def step(self) -> None:
        torch = self._torch
        with torch.no_grad():
            torch._foreach_add_(self.steps, 1)
            torch._fused_adam_(
                self.parameters,
                [p.grad for p in self.parameters],
                self.exp_avgs,
                self.exp_avg_sqs,
                [],
                self.steps,
                amsgrad=False,
                lr=self.lr,
                beta1=self.betas[0],
                beta2=self.betas[1],
                weight_decay=0.0,
                eps=self.eps,
                maximize=False,
                grad_scale=None,
                found_inf=None,
            )


class DQN:
    """Q-learning with a multilayer perceptron, a replay buffer and an optional target network."""

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
    ) -> None:
        torch = import_torch()
        self._torch = torch
        if cpu_threads > 0:  # process-wide: torch has one intra-op thread pool
            # never more threads than cores this process may use: 1024 threads on 2 cores made
            # every update 65 times slower (1.9 against 121 updates/s measured), so a run that
            # asked for primary.cpu_threads = 1024 (inside its range) seemed to hang (issue 25)
            torch.set_num_threads(min(cpu_threads, usable_cores()))
        self.device = resolve_device(torch, device)
        self.n_actions = n_actions
        self.discount = discount
        self.batch_size = batch_size
        self.target_update_interval = target_update_interval
        generator = torch.Generator().manual_seed(int(seed))
        sizes = (observation_size, *hidden_sizes, n_actions)
        self.online = mlp(torch, sizes, generator).to(self.device)
        self.target = None
        if target_update_interval > 0:
            self.target = copy.deepcopy(self.online)
            self.target.requires_grad_(False)
        parameters = list(self.online.parameters())
        self.optimizer: Any
        if hasattr(torch, "_fused_adam_"):
            self.optimizer = FusedAdam(torch, parameters, learning_rate, eps=1e-7)
        else:  # pragma: no cover - torch < 2.4 has no fused Adam kernel
            self.optimizer = torch.optim.Adam(parameters, lr=learning_rate, eps=1e-7)
        self.buffer = ReplayBuffer(buffer_size, observation_size)
        self.updates = 0
        # Normalisation to [0, 1] with the observation space's bounds (None: raw observations).
        self._low: np.ndarray | None = None
        self._scale: np.ndarray | None = None
        if observation_low is not None and observation_high is not None:
            low = np.asarray(observation_low, dtype=np.float32)
            span = np.asarray(observation_high, dtype=np.float32) - low
            self._low = low
            self._scale = np.where(span > 0, 1.0 / np.where(span > 0, span, 1.0), 1.0).astype(np.float32)

    # ------------------------------------------------------------------ acting
    def normalise(self, observation: np.ndarray) -> np.ndarray:
        x = np.asarray(observation, dtype=np.float32)
        if self._scale is None or self._low is None:
            return x
        return (x - self._low) * self._scale

    def q_values(self, observation: np.ndarray) -> np.ndarray:
        """Q(s, .) of the online network for one observation."""
        torch = self._torch
        x = torch.from_numpy(self.normalise(observation)).to(self.device)
        with torch.no_grad():
            return self.online(x[None])[0].cpu().numpy()

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
        Returns the minibatch's loss before the step."""
        if len(self.buffer) < self.batch_size:
            return None
        torch, device = self._torch, self.device
        batch = self.buffer.sample(self.batch_size, rng)
        observations = torch.from_numpy(batch.observations).to(device)
        actions = torch.from_numpy(batch.actions).to(device)
        rewards = torch.from_numpy(batch.rewards).to(device)
        with torch.no_grad():
            if self.discount == 0.0:
                targets = rewards  # a bandit: every decision ends (SEQ)
            else:
                bootstrap = self.target if self.target is not None else self.online
                following = bootstrap(torch.from_numpy(batch.next_observations).to(device))
                alive = 1.0 - torch.from_numpy(batch.terminals).to(device)
                targets = rewards + self.discount * alive * following.max(dim=1).values
        predicted = self.online(observations).gather(1, actions[:, None]).squeeze(1)
        loss = torch.nn.functional.mse_loss(predicted, targets)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.updates += 1
        if self.target is not None and self.updates % self.target_update_interval == 0:
            self.target.load_state_dict(self.online.state_dict())
        return float(loss.detach())
