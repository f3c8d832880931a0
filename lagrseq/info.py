"""``lagrseq info``: what to paste into a bug report. The version, the Python, every extra of
lagrseq with the installed version of each of its packages (or "not installed"), the device torch
would use, and where each command writes by default.

Nothing here imports an extra at module level; torch is imported only to name its device, and
only where it is installed.
"""

from __future__ import annotations

import platform
import re
import sys
from collections.abc import Callable
from importlib import metadata
from pathlib import Path

from lagrseq import __version__

OUTPUTS = (
    ("run", "runs", ""),
    ("reproduce", "lagrseq-out", " (runs/ and reports/ inside)"),
    ("frontier", "frontier", " (the report in frontier/frontier/)"),
    ("audit", "audit", " (runs/ and reports/ inside)"),
)
"""(command, default output directory relative to the working directory, what lies inside);
each command's ``--out`` moves it."""

_EXTRA = re.compile(r"""extra\s*==\s*["']([^"']+)["']""")
_NAME = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)")


def extras(distribution: str = "lagrseq") -> dict[str, list[str]]:
    """extra -> the names of the packages it brings, from the installed metadata (empty when
    lagrseq runs from a source tree without being installed)."""
    try:
        requires = metadata.requires(distribution) or []
    except metadata.PackageNotFoundError:
        return {}
    out: dict[str, list[str]] = {}
    for line in requires:
        marker = _EXTRA.search(line)
        name = _NAME.match(line)
        if marker is None or name is None:
            continue
        out.setdefault(marker.group(1), []).append(name.group(1))
    return out


def installed(package: str) -> str | None:
    """The installed version of ``package``, or None."""
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


def torch_device() -> str:
    """What torch would run the DQN on, in words ("not installed" without the dqn extra)."""
    if installed("torch") is None:
        return "torch not installed (the dqn extra): the grid tasks' DQN is not available"
    try:
        import torch
    except Exception as exc:  # a broken install is worth reporting, not a traceback
        return f"torch is installed but does not import ({type(exc).__name__}: {exc})"
    if torch.cuda.is_available():
        names = ", ".join(torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count()))
        seen = f"cuda available ({names})"
    else:
        seen = "no GPU visible (cpu only)"
    return f"torch {torch.__version__}: {seen}; lagrseq uses the cpu unless primary.device says \"cuda\" or \"auto\""


def numerics_line() -> str:
    """The DQN's numerics (``LAGRSEQ_NUMERICS``, :mod:`lagrseq.agents.numerics`)."""
    from lagrseq.agents.numerics import PERTURBED, VARIABLE, numerics

    what = "another CPU simulated: initial weights one ulp up, minibatches summed in reverse order" if numerics() == PERTURBED else "this machine's own"
    return f"{numerics()} ({VARIABLE}; {what}; docs/reproduce.md)"


def lines(cwd: Path | None = None, device: Callable[[], str] = torch_device) -> list[str]:
    """The report, line by line."""
    cwd = Path.cwd() if cwd is None else cwd
    out = [
        f"lagrseq {__version__} ({Path(__file__).resolve().parent})",
        f"python {platform.python_version()} ({sys.executable}) on {platform.system()} {platform.machine()}",
    ]
    found = extras()
    if not found:
        out.append("extras: unknown (lagrseq is not installed; pip install -e . in the source tree)")
    for extra, packages in sorted(found.items()):
        versions = [f"{p} {installed(p) or 'not installed'}" for p in packages]
        state = "installed" if all(installed(p) for p in packages) else "not installed"
        out.append(f"extra {extra}: {state} ({', '.join(versions)})")
    out.append(f"torch device: {device()}")
    out.append(f"numerics: {numerics_line()}")
    for command, default, inside in OUTPUTS:
        out.append(f"output of {command}: {cwd / default}{inside}; --out moves it")
    return out
