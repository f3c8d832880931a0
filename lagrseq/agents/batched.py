"""The seed-batched backend of :class:`lagrseq.agents.dqn.DQN`: the networks of several agents of
one shape stacked in one :class:`NetworkGroup`, so that the trials of a lockstep run
(:mod:`lagrseq.agents.lockstep`) train in one batched call per step.

It computes what :class:`lagrseq.agents.dqn.Reference` computes (autograd, ``mse_loss``,
``torch.optim.Adam(fused=True)``), bit for bit for every member whoever else shares its call
(tests/agents/test_dqn.py). It is faster because it skips autograd and ``torch.optim``: the
backward pass is written out with the operations autograd runs, and Adam is the fused kernel
``torch.optim.Adam(fused=True)`` calls, reached directly (see :func:`fused_adam_step` for the
measured reasons). ``benchmarks/bench_train_step.py`` prints both speeds and checks the equality.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from typing import Any

import numpy as np

from lagrseq.agents import lockstep
from lagrseq.agents.replay import Batch, Draw

KERAS_EPSILON = 1e-7
"""Adam's epsilon in the released code (Keras' default)."""


def fused_adam_step(torch: Any, parameters: list[Any], grads: list[Any], exp_avgs: list[Any], exp_avg_sqs: list[Any],
                    steps: list[Any], lr: float, eps: float, betas: tuple[float, float] = (0.9, 0.999),
                    counters: list[Any] | None = None) -> None:
    """One Adam step of every parameter (Kingma and Ba; torch's defaults: betas 0.9 and 0.999, no
    weight decay), in place: the kernel ``torch.optim.Adam(..., fused=True)`` runs, with the same
    state tensors, so the same numbers bit for bit (tests/agents/test_dqn.py).

    The kernel reads each tensor as flat memory: every gradient must be contiguous. ``steps``:
    each parameter's step count, a float32 scalar tensor (the kernel only reads them);
    ``counters``: the distinct tensors among them, counted up first (default: ``steps``)."""
    with torch.no_grad():
        # Private torch API, for two measured reasons. (1) Members step at counts of their own
        # inside one call, and several parameters share one member's count: torch.optim keeps one
        # count per parameter and increments each. (2) Building any torch.optim optimizer imports
        # torch._dynamo: 0.75 s of CPU per process with torch 2.13 (1.6 to 2.2 s with 2.4), paid
        # by every process that builds an agent (tests/agents/test_dqn.py checks it is not).
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

    Each member keeps its own Adam state (its rows of the stacked moments and its own step
    count), target-network copy and update count, so any subset of members can take a step
    while the others stay untouched (Adam then runs over each member's views); when every
    member steps at one count, Adam runs over the stacked tensors in one piece where that gives
    each member's numbers (:data:`WHOLE_VECTORS`).
    The batched operations give each member the very numbers a network of its own gives
    (``nn.Sequential`` of ``nn.Linear``, ``mse_loss``, fused Adam), bit for bit
    (tests/agents/test_dqn.py): a member's results never depend on which members share its
    call. Acting (one observation) uses ``addmv`` per member, because that is what
    ``nn.Linear`` computes for one row; a batched product of one row sums in another order.
    """

    def __init__(self, torch: Any, sizes: Sequence[int], learning_rate: float, discount: float,
                 target_update_interval: int, device: Any) -> None:
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
        self._step_counts: Any = None
        """Adam's step count of every member, ``(members,)`` float32 (the kernel reads one
        per parameter tensor: views of it, ``_steps``)."""
        self._steps: list[Any] = []
        self.exp_avgs: list[Any] = []
        """Adam's first moments of every member, stacked as the parameters are: the weights of
        every layer, then the biases (:meth:`_state`'s order)."""
        self.exp_avg_sqs: list[Any] = []
        """Adam's second moments, stacked likewise."""
        self._whole: tuple[list[Any], list[Any], list[Any], list[int]] | None = None
        self._buffers: dict[tuple[Any, ...], tuple[dict[str, np.ndarray], dict[str, Any]]] = {}
        self.updates: list[int] = []
        self._states: dict[int, tuple[list[Any], list[Any], list[Any], list[Any]]] = {}
        self._target_states: dict[int, list[Any]] = {}
        self.threads = 0
        """torch's intra-op threads for the training calls (0: torch's default). OpenMP keeps
        the setting per thread, and in lockstep another thread than the agent's makes them."""
        self._threads_set: set[int] = set()
        self._everyone: list[int] = []

    def join(self, network: Any) -> int:
        """A new member starting from the weights of ``network`` (an ``nn.Sequential`` of
        ``nn.Linear`` and ReLU, :func:`lagrseq.agents.dqn.mlp`); returns its index."""
        tensors: list[Any] = []
        for i in range(self.layers):
            linear = network[2 * i]
            tensors += [linear.weight.detach().to(self.device), linear.bias.detach().to(self.device)]
        index = self._members + len(self._joining)
        self._joining.append(tensors)
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
        joining = len(self._joining)
        for j, parameter in enumerate([*self.weights, *self.biases]):  # Adam's moments: zero for the new members
            zeros = torch.zeros_like(parameter[self._members:])
            if self._members:
                self.exp_avgs[j] = torch.cat([self.exp_avgs[j], zeros])
                self.exp_avg_sqs[j] = torch.cat([self.exp_avg_sqs[j], zeros.clone()])
            else:
                self.exp_avgs.append(zeros)
                self.exp_avg_sqs.append(zeros.clone())
        zeros = torch.zeros(joining, dtype=torch.float32, device=self.device)
        self._step_counts = zeros if self._step_counts is None else torch.cat([self._step_counts, zeros])
        self._steps = list(self._step_counts.unbind(0))
        self._members += joining
        self._joining = []
        self._everyone = list(range(self._members))
        self._states, self._target_states, self._whole = {}, {}, None  # views of the tensors just replaced

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
    def _forward(self, weights: list[Any], biases: list[Any], x: Any) -> Any:
        torch = self._torch
        for i in range(self.layers):
            x = _linear(torch, x, weights[i], biases[i])
            if i < self.layers - 1:
                x = torch.relu(x)
        return x

    def train(self, requests: Sequence[tuple[int, Batch | Draw]]) -> list[float]:
        """One Adam step for each requesting member on its minibatch (``(member, batch)``, at
        most one request per member; a :class:`Draw` is copied straight into the stacked
        arrays); the other members are untouched. Returns each minibatch's loss before the
        step."""
        torch, device = self._torch, self.device
        self._stack()
        if self.threads and threading.get_ident() not in self._threads_set:
            torch.set_num_threads(self.threads)
            self._threads_set.add(threading.get_ident())
        # one request (a trial training alone) takes the same path: no autograd and no torch.optim,
        # faster than the reference on single matrices, the same numbers (bench_train_step.py)
        members = [member for member, _ in requests]
        index = None if members == self._everyone else torch.tensor(members, dtype=torch.int64, device=device)

        def rows(tensors: list[Any]) -> list[Any]:
            return tensors if index is None else [t.index_select(0, index) for t in tensors]

        arrays, tensors = self._batch_buffers(requests)
        for row, (_, batch) in enumerate(requests):
            if isinstance(batch, Draw):
                batch.copy_into(arrays, row)
            else:
                for name, array in arrays.items():
                    array[row] = getattr(batch, name)

        def stacked(name: str) -> Any:
            return tensors[name]

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
            weights, biases = rows(self.weights), rows(self.biases)
            losses, weight_grads, bias_grads = self._gradients(weights, biases, observations, actions, targets)
            counters = [self._steps[member] for member in members]
            updates = self.updates[members[0]]
            if index is None and all(self.updates[member] == updates for member in members):
                # every member, at one step count: the stacked tensors in one piece where that
                # gives the kernel's numbers per member (see _whole_state), the rest per member
                parameters, exp_avgs, exp_avg_sqs, apart = self._whole_state()
                gradients = [*weight_grads, *bias_grads]
                grads = [gradients[j] for j in range(len(gradients)) if j not in apart]
                grads += [gradients[j][row] if j < self.layers else gradients[j][row, 0]
                          for row in range(len(members)) for j in apart]
                fused_adam_step(torch, parameters, grads, exp_avgs, exp_avg_sqs, [counters[0]] * len(parameters),
                                self.learning_rate, KERAS_EPSILON, counters=[self._step_counts])
                self._count_everyone()
            else:
                parameters, grads, steps, exp_avgs, exp_avg_sqs = [], [], [], [], []
                for row, member in enumerate(members):
                    state = self._state(member)
                    parameters += state[0]
                    steps += state[1]
                    exp_avgs += state[2]
                    exp_avg_sqs += state[3]
                    grads += [g[row] for g in weight_grads] + [g[row, 0] for g in bias_grads]
                fused_adam_step(torch, parameters, grads, exp_avgs, exp_avg_sqs, steps, self.learning_rate,
                                KERAS_EPSILON, counters=counters)
                for member in members:
                    self._count(member)
        return losses.tolist()  # type: ignore[no-any-return]

    def _batch_buffers(self, requests: Sequence[tuple[int, Batch | Draw]]) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Arrays to stack the requests' minibatches in (one row per request), and the tensors
        on the group's device that hold them (on the CPU, the same memory), kept from call to
        call: only one call uses them at a time, and nothing of it outlives the call."""
        first = requests[0][1]
        if isinstance(first, Draw):
            rows = len(first.index)
            layout = [((rows, *column.shape[1:]), column.dtype)
                      for column in (getattr(first.buffer, name) for name in Batch._fields)]
        else:
            layout = [(value.shape, value.dtype) for value in first]
        key = (len(requests), *layout)
        buffers = self._buffers.get(key)
        if buffers is None:
            torch = self._torch
            arrays = {name: np.empty((len(requests), *shape), dtype=dtype)
                      for name, (shape, dtype) in zip(Batch._fields, layout, strict=True)}
            if self.discount == 0.0:  # a bandit bootstraps from nothing
                del arrays["next_observations"], arrays["terminals"]
            tensors = {name: torch.from_numpy(array) for name, array in arrays.items()}
            buffers = self._buffers[key] = (arrays, tensors)
        arrays, tensors = buffers
        if self.device.type != "cpu":
            tensors = {name: tensor.to(self.device) for name, tensor in tensors.items()}
        return arrays, tensors

    def _gradients(self, weights: list[Any], biases: list[Any], observations: Any, actions: Any,
                   targets: Any) -> tuple[Any, list[Any], list[Any]]:
        """Each member's loss (the mean squared error between Q(s, a) and its target) and its
        gradients with respect to each layer's weights ``(members, out, in)`` and biases
        ``(members, 1, out)``, contiguous as fused Adam reads them. The backward pass is written
        out with the operations autograd runs for ``nn.Linear``, ``relu``, ``gather`` and
        ``mse_loss`` (``threshold_backward``, ``scatter_add_``, ``mse_loss_backward``), so the
        numbers are autograd's bit for bit (tests/agents/test_dqn.py), without its
        bookkeeping, and the weights' gradient comes out in the weights' own layout (autograd
        gives a transposed view, which fused Adam misreads and which cost 16% of a step to copy)."""
        torch = self._torch
        # autograd's own backward operators, called directly: its numbers without its bookkeeping.
        # Measured with fused Adam called directly: 0.31 ms a step against the reference's 0.52 on
        # the image network, one thread (bench_train_step.py: reference / batched 1.67x)
        aten = torch.ops.aten
        inputs = []
        x = observations
        for i in range(self.layers):
            inputs.append(x)
            x = _linear(torch, x, weights[i], biases[i])
            if i < self.layers - 1:
                x = torch.relu(x)
        chosen = actions[:, :, None]
        predicted = x.gather(2, chosen).squeeze(2)
        losses = torch.nn.functional.mse_loss(predicted, targets, reduction="none").mean(dim=1)
        # d sum(losses) / d predicted: mean's backward (1 / batch), then mse_loss's (reduction none)
        grad = aten.mse_loss_backward(torch.ones_like(predicted).div_(predicted.shape[1]), predicted, targets, 0)
        grad = torch.zeros_like(x).scatter_add_(2, chosen, grad[:, :, None])  # gather's backward
        weight_grads: list[Any] = [None] * self.layers
        bias_grads: list[Any] = [None] * self.layers
        for i in reversed(range(self.layers)):
            weight_grads[i] = _bmm(torch, grad.transpose(1, 2), inputs[i])
            bias_grads[i] = grad.sum(1, keepdim=True)
            if i > 0:
                grad = aten.threshold_backward(_bmm(torch, grad, weights[i]), inputs[i], 0)  # relu's backward
        return losses, weight_grads, bias_grads

    def _count(self, member: int) -> None:
        """One more update of ``member``; its target copy is refreshed every interval."""
        self.updates[member] += 1
        if self.target_update_interval > 0 and self.updates[member] % self.target_update_interval == 0:
            with self._torch.no_grad():
                for online, target in zip(self._state(member)[0], self._target_state(member), strict=True):
                    target.copy_(online)

    def _count_everyone(self) -> None:
        """:meth:`_count` for every member, all at one update count: the target copies are
        refreshed in one piece."""
        self.updates[:] = [count + 1 for count in self.updates]
        if self.target_update_interval > 0 and self.updates[0] % self.target_update_interval == 0:
            for online, target in zip([*self.weights, *self.biases], [*self.target_weights, *self.target_biases],
                                      strict=True):
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
            exp_avgs, exp_avg_sqs = ([t[member] if j < self.layers else t[member, 0] for j, t in enumerate(stacked)]
                                     for stacked in (self.exp_avgs, self.exp_avg_sqs))
            state = self._states[member] = (
                [*weights, *biases], [self._steps[member]] * (2 * self.layers), exp_avgs, exp_avg_sqs,
            )
        return state

    def _whole_state(self) -> tuple[list[Any], list[Any], list[Any], list[int]]:
        """Adam's tensors for a step of every member at once: each stacked parameter whose
        members fill whole vectors of the fused kernel (:data:`WHOLE_VECTORS`), with its stacked
        moments, then every member's own views of the others; and the indices (in
        :meth:`_state`'s order) of the parameters taken per member."""
        if self._whole is None:
            parameters = [*self.weights, *self.biases]
            whole = [j for j, t in enumerate(parameters) if t[0].numel() % WHOLE_VECTORS == 0]
            apart = [j for j in range(len(parameters)) if j not in whole]
            per_member = [self._state(member) for member in range(self._members)]
            self._whole = (
                [parameters[j] for j in whole] + [state[0][j] for state in per_member for j in apart],
                [self.exp_avgs[j] for j in whole] + [state[2][j] for state in per_member for j in apart],
                [self.exp_avg_sqs[j] for j in whole] + [state[3][j] for state in per_member for j in apart],
                apart,
            )
        return self._whole


WHOLE_VECTORS = 64
"""Fused Adam on the CPU runs over a tensor's flat memory in vectors (16 floats with AVX-512),
the elements after the last whole vector one at a time, which rounds differently. A stacked
parameter whose members each hold a multiple of this many elements (enough for vectors of up to
2,048 bits) is stepped in one piece, every element where the member's own tensor puts it; the
others (the output layer's 2 biases) per member."""


SMALL_PRODUCT = 400
"""torch's ``bmm`` and ``baddbmm`` on the CPU compute a product of fewer multiply-adds than this
(per member) with a loop of their own instead of BLAS, which sums in another order than the
``mm`` and ``addmm`` of ``nn.Linear``; such products are computed per member."""


def _linear(torch: Any, x: Any, weight: Any, bias: Any) -> Any:
    """``x W^T + b`` for every member: ``(members, rows, in)`` by ``(members, out, in)`` plus
    ``(members, 1, out)``, as ``nn.Linear`` computes each member's."""
    if x.shape[1] * x.shape[2] * weight.shape[1] >= SMALL_PRODUCT:
        return torch.baddbmm(bias, x, weight.transpose(1, 2))
    return torch.stack([torch.addmm(bias[m, 0], x[m], weight[m].t()) for m in range(x.shape[0])])


def _bmm(torch: Any, a: Any, b: Any) -> Any:
    """``a @ b`` for every member, as ``mm`` computes each member's."""
    if a.shape[1] * a.shape[2] * b.shape[2] >= SMALL_PRODUCT:
        return torch.bmm(a, b)
    return torch.stack([torch.mm(a[m], b[m]) for m in range(a.shape[0])])



class Member:
    """One agent's network in a :class:`NetworkGroup`, with the interface of
    :class:`lagrseq.agents.dqn.Reference`; its training steps go through
    :func:`lagrseq.agents.lockstep.request`, so the trials of a lockstep run share calls."""

    def __init__(self, group: NetworkGroup, network: Any) -> None:
        self.group = group
        self.index = group.join(network)

    @property
    def updates(self) -> int:
        return self.group.updates[self.index]

    def parameters(self) -> list[Any]:
        return self.group.parameters(self.index)

    def target_parameters(self) -> list[Any] | None:
        return self.group.parameters(self.index, target=True) if self.group.target_update_interval > 0 else None

    def q_values(self, x: Any) -> Any:
        return self.group.q_values(self.index, x)

    def train(self, draw: Draw) -> float:
        return lockstep.request(self.group.train, (self.index, draw))  # type: ignore[no-any-return]
