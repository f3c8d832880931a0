"""The built-in tasks' registrations: what a plugin package's module holds, one module a task.

Each module here holds everything its task hands a run through its
:class:`~lagrseq.registry.TaskSpec` (``lagrseq.builtins`` names these functions by lazy
reference, as an entry point names a plugin's): the task and its env built from the
configuration, its mock profiles and extrapolator, its pictures, its guide, its state index and
its calibrated miss answer. ``lagrseq.running`` and ``lagrseq.loop`` reach a task only through
its spec, so a built-in task and a plugin task are wired the same way. The grid tasks share
:mod:`lagrseq.builtin_tasks.grid`.
"""
