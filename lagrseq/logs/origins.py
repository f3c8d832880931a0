"""Which distribution and version made each part of a trial: its task, provider kind, asking
policy and executor. Every log's run metadata names them (``parts``), and a rerun into a run's
directory is refused where a part now comes from another distribution or plugin version
(:func:`lagrseq.running.runner.check_resumable`).

A built-in part comes from ``lagrseq`` at its version; a plugin's from the distribution that
registered it (the registry records it when the plugin loads). The one place that asks the
registries: :func:`part_origin`.
"""

from __future__ import annotations

import json
from typing import Any

PARTS_METADATA = "parts"
"""The run metadata entry (JSON) naming each part: ``{"task": {"name": ..., "distribution": ...,
"version": ...}, "provider": ..., "policy": ..., "executor": {"distribution": ..., "version": ...}}``
(the executor without its name: a trial's log is the same bytes whichever executor ran it)."""
ROLES = ("task", "provider", "policy", "executor")
"""The parts of a trial, in the order they are shown."""
ANSWER_ROLES = ("task", "provider", "policy")
"""The parts whose code makes a trial's events (an executor only runs the trial: every executor
writes the same bytes, ``lagrseq.running.executors``)."""
BUILTIN_DISTRIBUTION = "lagrseq"
UNKNOWN = "unknown"


def part_origin(role: str, name: str) -> dict[str, str]:
    """``{"name", "distribution", "version"}`` of the part ``name`` registered as a ``role``
    (``task``, ``provider``, ``policy``, ``executor``; :func:`lagrseq.registry.part_origin`); an
    unregistered name is ``unknown``."""
    from lagrseq.errors import UsageError
    from lagrseq.registry import part_origin as registered

    try:
        distribution, version = registered(role, name)
    except UsageError:
        return {"name": name, "distribution": UNKNOWN, "version": UNKNOWN}
    return {"name": name, "distribution": distribution, "version": version}


def policy_name(config: Any) -> str | None:
    """The asking policy a trial of ``config`` runs: ``secondary.policy`` for ``lagr-seq``,
    ``always`` for ``lagr``, none for ``baseline``."""
    if config.method == "lagr":
        return "always"
    secondary = getattr(config, "secondary", None)
    return getattr(secondary, "policy", None) if config.method != "baseline" else None


def trial_parts_origins(config: Any, provider_spec: str, executor: str = "local") -> dict[str, dict[str, str]]:
    """Each part of a trial of ``config`` with ``--provider provider_spec`` run by ``executor``,
    by role (a trial without an asking policy has no ``policy``)."""
    names = {
        "task": config.task.name,
        "provider": provider_spec.partition(":")[0],
        "policy": policy_name(config),
        "executor": executor,
    }
    parts = {role: part_origin(role, name) for role, name in names.items() if name is not None}
    del parts["executor"]["name"]  # its code, not its name: every executor writes the same bytes
    return parts


def parts_json(parts: dict[str, dict[str, str]]) -> str:
    return json.dumps(parts, sort_keys=True)


def read_parts(text: Any) -> dict[str, dict[str, str]]:
    """A log's ``parts`` metadata; empty where it has none (a log made before it existed) or it
    cannot be read."""
    try:
        value = json.loads(text) if isinstance(text, str) and text else {}
    except (ValueError, RecursionError):
        return {}
    if not isinstance(value, dict):
        return {}
    return {
        str(role): {str(k): str(v) for k, v in part.items()}
        for role, part in value.items()
        if isinstance(part, dict)
    }


def origin_text(part: dict[str, str]) -> str:
    """``NAME (DISTRIBUTION VERSION)``, or ``DISTRIBUTION VERSION`` for a part logged without a
    name (the executor)."""
    made_by = f"{part.get('distribution', UNKNOWN)} {part.get('version', UNKNOWN)}"
    return f"{part['name']} ({made_by})" if part.get("name") else made_by


def identity(part: dict[str, str]) -> str:
    """What of a part must match for a log to be resumed: its distribution, and a plugin's
    version (a built-in part's version is lagrseq's, which a rerun may update, as it always could)."""
    distribution = part.get("distribution", UNKNOWN)
    if distribution == BUILTIN_DISTRIBUTION:
        return distribution
    return f"{distribution} {part.get('version', UNKNOWN)}"
