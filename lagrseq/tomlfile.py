"""The one TOML reader of lagrseq: configuration files, suite files and price tables.

A file named on the command line is untrusted: it may be missing, a directory, unreadable,
binary, not UTF-8, not TOML, nested thousands deep or gigabytes long. :func:`read_toml` turns
each of these into one :class:`~lagrseq.errors.ConfigError` line that names the path and the
problem, and reads at most :data:`MAX_TOML_BYTES` bytes (a device such as ``/dev/zero`` is refused
as too large rather than read for ever). Standard library only, so every layer may import it.
"""

from __future__ import annotations

import os
import sys
from typing import Any

from lagrseq.errors import ConfigError
from lagrseq.paths import expand_user
from lagrseq.text import kind_of

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

MAX_TOML_BYTES = 1 << 20
"""The largest TOML file read (1 MiB; the packaged paper suite is about 18 kB)."""


def shown(path: str | os.PathLike[str]) -> str:
    """``path`` for a one-line message: as written, or escaped when it holds control characters
    (a newline in a file name must not break the line)."""
    text = os.fspath(path)
    return text if text.isprintable() else ascii(text)


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def loads(text: str, where: str) -> dict[str, Any]:
    """Parse TOML ``text``; ``where`` starts the error message (e.g. ``config file x.toml``)."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{where} is not valid TOML: {_one_line(str(exc))}") from None
    except RecursionError:
        raise ConfigError(f"{where} is not usable TOML: its arrays or tables are nested too deeply") from None
    except ValueError as exc:  # an integer of more than 4300 digits (sys.get_int_max_str_digits)
        raise ConfigError(f"{where} is not usable TOML: {_too_long(exc)}") from None


def _too_long(exc: ValueError) -> str:
    return "it holds an integer of more than 4300 digits" if "digits" in str(exc) else _one_line(str(exc))


def read_toml(path: str | os.PathLike[str], what: str = "config", max_bytes: int = MAX_TOML_BYTES) -> dict[str, Any]:
    """Read the TOML file ``path``; ``what`` names its role in messages (``config``, ``suite``,
    ``price table``). Every failure is one ConfigError line naming the path and the problem."""
    where = f"{what} file {shown(path)}"
    try:
        file = expand_user(path, f"{what} file", ConfigError)
        if file.is_dir():
            raise ConfigError(f"{where} is a directory; expected a TOML file")
        if file.exists() and not file.is_file() and str(file) != os.devnull:  # a FIFO or a device (/dev/null: empty)
            raise ConfigError(f"{where} is {kind_of(file.stat().st_mode)}; expected a TOML file")
        with file.open("rb") as handle:
            data = handle.read(max_bytes + 1)
    except ConfigError:
        raise
    except FileNotFoundError:
        raise ConfigError(f"{where} does not exist") from None
    except PermissionError:
        raise ConfigError(f"{where} cannot be read: permission denied") from None
    except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the path
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise ConfigError(f"{where} cannot be read: {_one_line(reason)}") from None
    if len(data) > max_bytes:
        raise ConfigError(f"{where} is larger than {max_bytes} bytes; a TOML {what} file is a few kB")
    if b"\x00" in data:
        raise ConfigError(f"{where} holds NUL bytes (binary data at offset {data.index(0)}); expected a TOML file")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{where} is not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}); expected a TOML file"
        ) from None
    return loads(text, where)


def value_of(raw: str) -> Any:
    """The one TOML value written as ``raw`` (``100``, ``0.5``, ``nan``, ``true``, ``"text"``,
    ``[1, 2]``), or ``raw`` stripped when it is not exactly one TOML value (a bare string).
    Raises ValueError for a value nested too deeply to parse."""
    try:
        parsed = tomllib.loads(f"v = {raw}")
    except tomllib.TOMLDecodeError:
        return raw.strip()
    except RecursionError:
        raise ValueError("its arrays or tables are nested too deeply") from None
    except ValueError as exc:
        raise ValueError(_too_long(exc)) from None
    return parsed["v"] if set(parsed) == {"v"} else raw.strip()
