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

Seed-batched: every agent's network is a member of a :class:`NetworkGroup`, which stacks the
networks of one shape; in a lockstep run (:mod:`lagrseq.agents.lockstep`) the trials' agents share
groups and train in one batched call per step, with exactly the numbers each network gets alone.
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Sequence
from typing import Any

import numpy as np

from lagrseq.agents import lockstep
from lagrseq.agents.replay import Batch, ReplayBuffer
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


def fused_adam_step(torch: Any, parameters: list[Any], grads: list[Any], exp_avgs: list[Any], exp_avg_sqs: list[Any],
                    steps: list[Any], lr: float, eps: float, betas: tuple[float, float] = (0.9, 0.999),
                    counters: list[Any] | None = None) -> None:
    """One Adam step of every parameter (Kingma and Ba; torch's defaults: betas 0.9 and 0.999, no
    weight decay), in place, in one call of the fused kernel ``torch.optim.Adam(..., fused=True)``
    runs, with the same state tensors: the same numbers bit for bit (tests/agents/test_dqn.py),
    without ``torch.optim``'s machinery. Constructing any ``torch.optim`` optimizer imports
    ``torch._dynamo`` (its ``add_param_group`` is wrapped in ``torch._disable_dynamo``), 1.6 to
    2.2 s of CPU in every process that builds an agent, for a compiler lagrseq never uses.

    The kernel reads each tensor as flat memory: every gradient must be contiguous. ``steps``:
    each parameter's step count, a float32 scalar tensor (the kernel only reads them);
    ``counters``: the distinct tensors among them, counted up first (default: ``steps``)."""
    with torch.no_grad():
        torch._foreach_add_(steps if counters is None else counters, 1)
        torch._fused_adam_(
            parameters, grads, exp_avgs, exp_avg_sqs, [], steps, amsgrad=False, lr=lr, beta1=betas[0],
            beta2=betas[1], weight_decay=0.0, eps=eps, maximize=False, grad_scale=None, found_inf=None,
        )


class NetworkGroup:
    """The networks of several DQN agents of one shape, stacked: layer i's weights of every
    member in one ``(members, out, in)`` tensor (``nn.Linear``'s layout) and its biases in one
    ``(members, 1, out)`` tensor, so that one training step of many members is one ``baddbmm``
    per layer, forward and backward, and one Adam call.

    Each member keeps its own Adam state (over views of its slices), target-network copy and
    update count, so any subset of members can take a step while the others stay untouched.
    The batched operations give each member the very numbers a network of its own gives
    (``nn.Sequential`` of ``nn.Linear``, ``mse_loss``, fused Adam), bit for bit
    (tests/agents/test_dqn.py): a member's results never depend on which members share its
    call. Acting (one observation) uses ``addmv`` per member, because that is what
    ``nn.Linear`` computes for one row; a batched product of one row sums in another order.
    """

    def __init__(self, torch: Any, sizes: Sequence[int], learning_rate: float, discount: float,
                 target_update_interval: int, device: Any) -> None:
        if not hasattr(torch, "_fused_adam_"):  # pragma: no cover - torch 2.2 and 2.3
            raise UsageError(
                f"the DQN agents need torch's fused Adam kernel (torch 2.4 or newer), found torch {torch.__version__}; "
                "pip install -U 'lagrseq[dqn]'"
            )
        self._torch = torch
        self.sizes = tuple(sizes)
        self.learning_rate = learning_rate
        self.discount = discount
        self.target_update_interval = target_update_interval
        self.device = device
        self.layers = len(sizes) - 1
        self.weights: list[Any] = []
        """Per layer: the members' weights, ``(members, out, in)``."""
        self.biases: list[Any] = []
        """Per layer: the members' biases, ``(members, 1, out)``."""
        self.target_weights: list[Any] = []
        self.target_biases: list[Any] = []
        self._joining: list[list[Any]] = []
        self._members = 0
        # per member: Adam's step counts and moments (one per parameter), update count
        self._steps: list[Any] = []
        self._exp_avgs: list[list[Any]] = []
        self._exp_avg_sqs: list[list[Any]] = []
        self.updates: list[int] = []
        self._states: dict[int, tuple[list[Any], list[Any], list[Any], list[Any]]] = {}
        self._target_states: dict[int, list[Any]] = {}
        self.threads = 0
        """torch's intra-op threads for the training calls (0: torch's default). OpenMP keeps
        the setting per thread, and in lockstep another thread than the agent's makes them."""
        self._threads_set: set[int] = set()
        self._everyone: list[int] = []

    def join(self, generator: Any) -> int:
        """A new member with weights drawn as :func:`mlp` draws them; returns its index."""
        torch = self._torch
        network = mlp(torch, self.sizes, generator)
        tensors: list[Any] = []
        for i in range(self.layers):
            linear = network[2 * i]
            tensors += [linear.weight.detach().to(self.device), linear.bias.detach().to(self.device)]
        index = self._members + len(self._joining)
        self._joining.append(tensors)
        ordered = tensors[0::2] + tensors[1::2]  # the weights of every layer, then the biases
        self._steps.append(torch.zeros((), dtype=torch.float32, device=self.device))  # one count per member
        self._exp_avgs.append([torch.zeros_like(t) for t in ordered])
        self._exp_avg_sqs.append([torch.zeros_like(t) for t in ordered])
        self.updates.append(0)
        return index

    def _stack(self) -> None:
        """Members that joined since the last call get their rows in the stacked tensors."""
        if not self._joining:
            return
        torch = self._torch
        for i in range(self.layers):
            weights = torch.stack([t[2 * i] for t in self._joining])
            biases = torch.stack([t[2 * i + 1][None] for t in self._joining])
            if self._members:
                weights = torch.cat([self.weights[i], weights])
                biases = torch.cat([self.biases[i], biases])
                if self.target_update_interval > 0:
                    self.target_weights[i] = torch.cat([self.target_weights[i], weights[self._members:]])
                    self.target_biases[i] = torch.cat([self.target_biases[i], biases[self._members:]])
                self.weights[i], self.biases[i] = weights, biases
            else:
                self.weights.append(weights)
                self.biases.append(biases)
                if self.target_update_interval > 0:
                    self.target_weights.append(weights.clone())
                    self.target_biases.append(biases.clone())
        self._members += len(self._joining)
        self._joining = []
        self._everyone = list(range(self._members))
        self._states, self._target_states = {}, {}  # views of the tensors just replaced

    def parameters(self, member: int, target: bool = False) -> list[Any]:
        """A member's weights and biases, layer by layer (views: ``nn.Linear``'s shapes)."""
        self._stack()
        weights, biases = (self.target_weights, self.target_biases) if target else (self.weights, self.biases)
        return [t for i in range(self.layers) for t in (weights[i][member], biases[i][member, 0])]

    # ------------------------------------------------------------------ acting
    def q_values(self, member: int, x: Any) -> Any:
        """Q(s, .) of one member's online network for one observation (a 1-D tensor)."""
        torch = self._torch
        self._stack()
        with torch.no_grad():
            for i in range(self.layers):
                x = torch.addmv(self.biases[i][member, 0], self.weights[i][member], x)
                if i < self.layers - 1:
                    x = torch.relu(x)
        return x

    # ------------------------------------------------------------------ learning
    def _forward(self, weights: list[Any], biases: list[Any], x: Any, grad: bool = False) -> Any:
        torch = self._torch
        linear = batched_linear(torch).apply if grad else None
        for i in range(self.layers):
            if linear is None:
                x = torch.baddbmm(biases[i], x, weights[i].transpose(1, 2))
            else:
                x = linear(x, weights[i], biases[i])
            if i < self.layers - 1:
                x = torch.relu(x)
        return x

    def train(self, requests: Sequence[tuple[int, Batch]]) -> list[float]:
        """One Adam step for each requesting member on its minibatch (``(member, batch)``, at
        most one request per member); the other members are untouched. Returns each
        minibatch's loss before the step."""
        torch, device = self._torch, self.device
        self._stack()
        if self.threads and threading.get_ident() not in self._threads_set:
            torch.set_num_threads(self.threads)
            self._threads_set.add(threading.get_ident())
        if len(requests) == 1:
            return [self._train_one(*requests[0])]
        members = [member for member, _ in requests]
        index = None if members == self._everyone else torch.tensor(members, dtype=torch.int64, device=device)

        def rows(tensors: list[Any]) -> list[Any]:
            return tensors if index is None else [t.index_select(0, index) for t in tensors]

        def stacked(name: str) -> Any:
            return torch.from_numpy(np.stack([getattr(batch, name) for _, batch in requests])).to(device)

        observations, actions, rewards = stacked("observations"), stacked("actions"), stacked("rewards")
        with torch.no_grad():
            if self.discount == 0.0:
                targets = rewards  # a bandit: every decision ends (SEQ)
            else:
                if self.target_update_interval > 0:
                    weights, biases = rows(self.target_weights), rows(self.target_biases)
                else:
                    weights, biases = rows(self.weights), rows(self.biases)
                following = self._forward(weights, biases, stacked("next_observations"))
                alive = 1.0 - stacked("terminals")
                targets = rewards + self.discount * alive * following.max(dim=2).values
        weights = [t.detach().requires_grad_() for t in rows(self.weights)]
        biases = [t.detach().requires_grad_() for t in rows(self.biases)]
        predicted = self._forward(weights, biases, observations, grad=True).gather(2, actions[:, :, None]).squeeze(2)
        losses = torch.nn.functional.mse_loss(predicted, targets, reduction="none").mean(dim=1)
        gradients = torch.autograd.grad(losses.sum(), [*weights, *biases])
        # per member and parameter, in the order of _state
        per_layer = [g.unbind(0) for g in gradients[: self.layers]]
        per_layer += [g.squeeze(1).unbind(0) for g in gradients[self.layers:]]
        parameters: list[Any] = []
        grads: list[Any] = []
        steps: list[Any] = []
        exp_avgs: list[Any] = []
        exp_avg_sqs: list[Any] = []
        counters: list[Any] = []
        for row, member in enumerate(members):
            state = self._state(member)
            parameters += state[0]
            steps += state[1]
            counters.append(self._steps[member])
            exp_avgs += state[2]
            exp_avg_sqs += state[3]
            grads += [layer[row] for layer in per_layer]
        fused_adam_step(torch, parameters, grads, exp_avgs, exp_avg_sqs, steps, self.learning_rate, KERAS_EPSILON,
                        counters=counters)
        for member in members:
            self._count(member)
        return losses.detach().tolist()  # type: ignore[no-any-return]

    def _train_one(self, member: int, batch: Batch) -> float:
        """:meth:`train` for one member: the same step with its own slices (``linear`` on
        matrices, as ``nn.Linear`` computes; the numbers of a batch of one, a little faster)."""
        torch, device = self._torch, self.device
        functional = torch.nn.functional
        parameters, steps, exp_avgs, exp_avg_sqs = self._state(member)

        def forward(tensors: list[Any], x: Any) -> Any:
            for i in range(self.layers):
                x = functional.linear(x, tensors[i], tensors[self.layers + i])
                if i < self.layers - 1:
                    x = torch.relu(x)
            return x

        observations = torch.from_numpy(batch.observations).to(device)
        actions = torch.from_numpy(batch.actions).to(device)
        rewards = torch.from_numpy(batch.rewards).to(device)
        with torch.no_grad():
            if self.discount == 0.0:
                targets = rewards
            else:
                bootstrap = self._target_state(member) if self.target_update_interval > 0 else parameters
                following = forward(bootstrap, torch.from_numpy(batch.next_observations).to(device))
                alive = 1.0 - torch.from_numpy(batch.terminals).to(device)
                targets = rewards + self.discount * alive * following.max(dim=1).values
        leaves = [t.detach().requires_grad_() for t in parameters]
        predicted = forward(leaves, observations).gather(1, actions[:, None]).squeeze(1)
        loss = functional.mse_loss(predicted, targets)
        grads = list(torch.autograd.grad(loss, leaves))
        fused_adam_step(torch, parameters, grads, exp_avgs, exp_avg_sqs, steps, self.learning_rate, KERAS_EPSILON,
                        counters=[self._steps[member]])
        self._count(member)
        return float(loss.detach())

    def _count(self, member: int) -> None:
        """One more update of ``member``; its target copy is refreshed every interval."""
        self.updates[member] += 1
        if self.target_update_interval > 0 and self.updates[member] % self.target_update_interval == 0:
            with self._torch.no_grad():
                for online, target in zip(self._state(member)[0], self._target_state(member), strict=True):
                    target.copy_(online)

    def _target_state(self, member: int) -> list[Any]:
        """A member's target parameters, in the order of :meth:`_state`."""
        state = self._target_states.get(member)
        if state is None:
            weights = [w[member] for w in self.target_weights]
            biases = [b[member, 0] for b in self.target_biases]
            state = self._target_states[member] = [*weights, *biases]
        return state

    def _state(self, member: int) -> tuple[list[Any], list[Any], list[Any], list[Any]]:
        """A member's parameters (views: the weights of every layer, then the biases), Adam
        step counts, first and second moments, as the fused kernel takes them."""
        state = self._states.get(member)
        if state is None:
            weights = [w[member] for w in self.weights]
            biases = [b[member, 0] for b in self.biases]
            state = self._states[member] = (
                [*weights, *biases], [self._steps[member]] * (2 * self.layers), self._exp_avgs[member],
                self._exp_avg_sqs[member],
            )
        return state


KERAS_EPSILON = 1e-7


@functools.cache
def batched_linear(torch: Any) -> Any:
    """``y = x W^T + b`` for stacked members (``baddbmm``, as in the forward pass everywhere
    here), with the backward pass written out so that the weights' gradient comes out in the
    weights' own layout, ``(members, out, in)`` and contiguous, as fused Adam needs it
    (autograd's own gives a transposed view, and copying it cost 16% of a step). Each product
    is the one ``nn.Linear``'s backward computes for one member (tests/agents/test_dqn.py
    checks the weights bit for bit)."""

    class BatchedLinear(torch.autograd.Function):  # type: ignore[misc,name-defined]
        @staticmethod
        def forward(ctx: Any, x: Any, weight: Any, bias: Any) -> Any:
            ctx.save_for_backward(x, weight)
            return torch.baddbmm(bias, x, weight.transpose(1, 2))

        @staticmethod
        def backward(ctx: Any, grad: Any) -> Any:
            x, weight = ctx.saved_tensors
            grad_x = torch.bmm(grad, weight) if ctx.needs_input_grad[0] else None
            return grad_x, torch.bmm(grad.transpose(1, 2), x), grad.sum(1, keepdim=True)

    return BatchedLinear
"""Adam's epsilon in the released code (Keras' default)."""


class DQN:
    """Q-learning with a multilayer perceptron, a replay buffer and an optional target network.

    The network is one member of a :class:`NetworkGroup`: in a lockstep run
    (:mod:`lagrseq.agents.lockstep`) the trials' agents of one shape share a group and train in
    one batched call; alone, an agent is a group of one (the same code)."""

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
        threads = 0
        if cpu_threads > 0:
            # never more threads than cores this process may use: 1024 threads on 2 cores made
            # every update 65 times slower (1.9 against 121 updates/s measured), so a run that
            # asked for primary.cpu_threads = 1024 (inside its range) seemed to hang (issue 25)
            threads = min(cpu_threads, usable_cores())
            torch.set_num_threads(threads)
        self.device = resolve_device(torch, device)
        self.n_actions = n_actions
        self.discount = discount
        self.batch_size = batch_size
        self.target_update_interval = target_update_interval
        generator = torch.Generator().manual_seed(int(seed))
        sizes = (observation_size, *hidden_sizes, n_actions)
        # trials of different runs may meet in one conductor: only networks whose batched calls
        # fit together (shapes, minibatch size, hyperparameters, device, threads) share a group
        key = ("dqn", sizes, batch_size, learning_rate, discount, target_update_interval, str(self.device), threads)

        def make() -> NetworkGroup:
            return NetworkGroup(torch, sizes, learning_rate, discount, target_update_interval, self.device)

        conductor = lockstep.current()
        self.group: NetworkGroup = make() if conductor is None else conductor.shared(key, make)
        self.member = self.group.join(generator)
        self.group.threads = threads
        self.buffer = ReplayBuffer(buffer_size, observation_size)
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
        return self.group.updates[self.member]

    def parameters(self) -> list[Any]:
        """The online network's weights and biases, layer by layer (``nn.Linear``'s shapes)."""
        return self.group.parameters(self.member)

    def target_parameters(self) -> list[Any] | None:
        """The target network's, or None without one (bootstrap from the online network)."""
        return self.group.parameters(self.member, target=True) if self.target_update_interval > 0 else None

    # ------------------------------------------------------------------ acting
    def normalise(self, observation: np.ndarray) -> np.ndarray:
        x = np.asarray(observation, dtype=np.float32)
        if self._scale is None or self._low is None:
            return x
        return (x - self._low) * self._scale

    def q_values(self, observation: np.ndarray) -> np.ndarray:
        """Q(s, .) of the online network for one observation."""
        x = self._torch.from_numpy(self.normalise(observation)).to(self.device)
        return self.group.q_values(self.member, x).cpu().numpy()  # type: ignore[no-any-return]

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
        batch = self.buffer.sample(self.batch_size, rng)
        return lockstep.request(self.group.train, (self.member, batch))  # type: ignore[no-any-return]
