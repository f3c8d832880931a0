"""``LAGRSEQ_NUMERICS``: another machine's floating point, simulated on this one.

A DQN run is bit-identical only on one machine with one build of torch and its BLAS: on another
CPU the network's sums come out in another order, the results differ in their last bits once the
network learns, and the grid trajectories part (DESIGN section 12). Tabular runs (the cube) do
not depend on it. To let a test meet that divergence on the machine that made the references,
the environment variable ``LAGRSEQ_NUMERICS`` chooses the DQN's numerics:

- ``native`` (the default, also when the variable is unset or empty): the numbers this machine's
  torch gives; the golden-log and determinism tests run so.
- ``perturbed``: every parameter of every network starts one unit in the last place higher
  (:func:`perturb`, ``torch.nextafter`` toward +inf after the seeded initialisation), and every
  training step sums its minibatch's rows in reverse order (:func:`reorder`: the same rows, the
  same loss in exact arithmetic, rounded otherwise in the gradients' sums, as another CPU's
  matrix kernels round them). Adam's normalised steps carry those last-bit differences into
  other greedy actions once the network steers the agent. The same seed under ``perturbed``
  still gives the same bytes on one machine. (The one-ulp start alone is not enough: that
  difference stays below the weights' rounding, and image-completion trials of 2,000 steps
  stayed identical to native ones.)

Anything else is refused (:func:`numerics`: one line, exit status 2). Like the BLAS a torch was
built with, the setting is a property of the machine a trial ran on, not of the experiment: it
is no configuration field and does not change a run directory's name or digest; a trial that
trains a network records ``numerics = "perturbed"`` in its log's run metadata (nothing under
``native``, so native logs keep their bytes), and resuming a run under another setting is
refused (:func:`lagrseq.running.runner.check_resumable`).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from lagrseq.errors import UsageError

VARIABLE = "LAGRSEQ_NUMERICS"
NATIVE = "native"
PERTURBED = "perturbed"
CHOICES = (NATIVE, PERTURBED)


def numerics(environ: Any = None) -> str:
    """The numerics ``LAGRSEQ_NUMERICS`` asks for (``native`` when unset or empty); any other value
    is a :class:`~lagrseq.errors.UsageError`."""
    value = (os.environ if environ is None else environ).get(VARIABLE, "")
    if value in ("", NATIVE):
        return NATIVE
    if value == PERTURBED:
        return PERTURBED
    shown = value if len(value) <= 40 else value[:40] + "..."
    raise UsageError(
        f"{VARIABLE}={shown!r} is not a numerics setting; expected one of {', '.join(CHOICES)} "
        f"(or unset: {NATIVE}); unset it or set {VARIABLE}={PERTURBED} to simulate another CPU"
    )


def perturb(torch: Any, tensors: list[Any]) -> None:
    """Under ``perturbed`` numerics, every element of each tensor one ulp toward +inf, in place
    (a network's freshly drawn weights and biases); under ``native``, nothing."""
    if numerics() != PERTURBED:
        return
    with torch.no_grad():
        for tensor in tensors:
            tensor.copy_(torch.nextafter(tensor, torch.full_like(tensor, float("inf"))))


def reorder(index: np.ndarray) -> np.ndarray:
    """A minibatch's rows in the order ``perturbed`` numerics sums them: reversed (the same rows,
    so the same loss in exact arithmetic, rounded in another order)."""
    return np.ascontiguousarray(index[::-1])
