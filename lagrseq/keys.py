"""Keeping the API key (and any other secret lagrseq was given) out of everything it prints or writes.

A server may echo the key it was sent: in the answer text, the ``model`` field, an error message,
a header, whole or in part (without its ``sk-`` prefix, upper-cased, split over two fields, with a
zero-width space every few characters). A user may paste it where a URL belongs. Two guards:

- :class:`Redactor`: every string that came back from a server passes through
  :meth:`Redactor.text` (built from the key that provider sent) before it is put in an answer, a
  store, an exception message or a callback.
- :func:`scrub`: the process-wide guard, built from the keys in the environment variables lagrseq
  reads (``OPENAI_API_KEY`` and every ``--api-key-env`` a provider was built with, :func:`watch`)
  and the secrets it was handed (the robot's token, :func:`remember`). Every line the command
  line prints on error, every MCAP metadata value and ``/query`` record, every store write and
  every ``--base-url`` (:func:`holds_key`: refused, never repeated) goes through it.

What counts as the key: the whole key, and every run of the text in which each window of
:data:`MIN_FRAGMENT` characters is a substring of the key (so every substring of the key at least
that long, and overlapping chains of them). Matching ignores ASCII case, and it ignores invisible
characters: format characters (Unicode category Cf: zero-width spaces and joiners, bidi marks, soft
hyphens, tag characters), control characters, whitespace and variation selectors are removed
before matching, and the run replaced in the original text spans what was removed inside it.
``MIN_FRAGMENT`` is 8: API keys are random base-62 strings (OpenAI's are ``sk-proj-`` and about
160 characters, vLLM's whatever the operator chose), and 8 random base-62 characters carry about
48 bits, so an 8-character window of a key turning up in an innocent answer by chance is
negligible, while any echo long enough to be recognised as part of the key (and to help anyone
guess it) is caught. Not matched: pieces shorter than 8 characters (a key split into pieces of 7
with other text between), and the key transformed (base64, hex, reversed, URL-escaped as
``%73%6B``, letters swapped for look-alikes such as full-width or Cyrillic ones). A key shorter
than 8 characters is redacted by a provider's :class:`Redactor` only whole and only in its own
case, and never by :func:`scrub` (such a key, ``EMPTY`` or ``ollama`` for a local server, is no
secret and is easily mistaken for ordinary words, which should not be blanked out of answers).

The scan is linear in the text: every window is packed into one 64-bit integer (8 characters of
8 bits: the key is printable ASCII and anything else maps to a code no key has) and looked up among
the key's windows with numpy, so a 4 MiB body takes at most a few hundred milliseconds whatever it holds (the
invisible characters are found with one Unicode lookup per distinct non-ASCII character).
"""

from __future__ import annotations

import json
import os
import re
import unicodedata
from collections.abc import Iterable
from typing import Any

import numpy as np

MIN_FRAGMENT = 8
"""Shortest substring of the key that is recognised and redacted (module docstring)."""
MARK = "[REDACTED]"
"""What a redacted run is replaced with."""

_KEY_LIKE = re.compile(r"\b(sk|key|api[_-]?key)[-_][A-Za-z0-9_\-*.]{6,}", re.IGNORECASE)
_NOT_ASCII = 0x80  # the code of every non-ASCII character in a packed window (never in a key)


def _codes(text: str, fold: bool) -> np.ndarray:
    """The characters of ``text`` as uint8 codes: ASCII (lower-cased if ``fold``), everything else
    0x80."""
    if text.isascii():
        data = text.encode("ascii")
        return np.frombuffer(data.lower() if fold else data, dtype=np.uint8)
    wide = _wide(text)
    if fold:
        wide = np.where((wide >= 65) & (wide <= 90), wide + 32, wide)
    return np.minimum(wide, _NOT_ASCII).astype(np.uint8)


def _wide(text: str) -> np.ndarray:
    """The code points of ``text`` (lone surrogates included)."""
    return np.frombuffer(text.encode("utf-32-le", "surrogatepass"), dtype="<u4")


_EXTRA_INVISIBLE = frozenset((0x034F, 0x115F, 0x1160, 0x3164, 0xFFA0, *range(0x180B, 0x1810), *range(0xFE00, 0xFE10), *range(0xE0100, 0xE01F0)))
"""Characters shown as nothing that are not format characters: the combining grapheme joiner,
the Hangul fillers, the Mongolian and the other variation selectors."""
_INVISIBLE_CATEGORIES = frozenset(("Cf", "Cc", "Zs", "Zl", "Zp"))


def invisible(char: str) -> bool:
    """Whether ``char`` is removed before matching: a format or control character, whitespace,
    a variation selector or a filler (the module docstring)."""
    return char.isspace() or unicodedata.category(char) in _INVISIBLE_CATEGORIES or ord(char) in _EXTRA_INVISIBLE


def _hidden(text: str) -> np.ndarray | None:
    """A mask of the invisible characters of ``text``; None when it has none."""
    if text.isascii():
        codes = np.frombuffer(text.encode("ascii"), dtype=np.uint8)
        mask = (codes <= 32) | (codes == 127)
    else:
        wide = _wide(text)
        mask = (wide <= 32) | (wide == 127)
        high = wide >= 0x80
        if high.any():
            distinct = np.unique(wide[high])  # one Unicode lookup per distinct character
            hidden = np.array([invisible(chr(c)) for c in distinct.tolist()], dtype=bool)
            if hidden.any():
                mask |= np.isin(wide, distinct[hidden])
    return mask if mask.any() else None


def _windows(codes: np.ndarray, width: int) -> np.ndarray:
    """Every ``width``-character window of ``codes`` packed into one uint64, first character in
    the high byte (8 bytes read at every offset of the codes, the unused low bytes shifted out)."""
    count = len(codes) - width + 1
    if count <= 0:
        return np.zeros(0, dtype=np.uint64)
    padded = np.concatenate((codes, np.zeros(8, dtype=np.uint8)))  # every 8-byte read stays inside
    packed = np.ndarray((count,), dtype=">u8", buffer=padded, strides=(1,)).astype(np.uint64)
    if width < 8:
        packed >>= np.uint64(8 * (8 - width))
    return packed


class Redactor:
    """Blanks a secret, and every recognisable fragment of it, out of text (module docstring)."""

    __slots__ = ("_fold", "_grams", "_pairs", "_width")

    def __init__(self, secret: str, min_fragment: int = MIN_FRAGMENT) -> None:
        if not 1 <= min_fragment <= 8:
            raise ValueError("min_fragment must be between 1 and 8 (8 characters fill 64 bits)")
        self._width = min(min_fragment, len(secret))
        self._fold = len(secret) >= min_fragment  # a short key is matched in its own case only
        if not secret or not secret.isascii():
            self._grams = np.zeros(0, dtype=np.uint64)  # nothing to find (a non-ASCII key is refused)
            self._pairs = np.zeros(0, dtype=bool)
            return
        codes = _codes(secret, self._fold)
        if len(secret) < min_fragment:  # too short for fragments to mean anything: the whole key only
            self._grams = _windows(codes, len(secret))[:1]
        else:
            self._grams = np.unique(_windows(codes, self._width))
        # A quick first filter: the last two characters of every window of the key.
        self._pairs = np.zeros(1 << 16, dtype=bool)
        self._pairs[(self._grams & np.uint64(0xFFFF)).astype(np.intp)] = True

    def __repr__(self) -> str:
        return "Redactor(****)"

    def __reduce__(self) -> Any:
        raise TypeError("refusing to pickle a redactor (it is built from an API key)")

    def text(self, text: str) -> str:
        """``text`` with every run made of the secret's windows replaced by :data:`MARK`; the
        invisible characters of ``text`` are skipped in matching and replaced with the run they
        sit in."""
        width = self._width
        if not self._grams.size or len(text) < width:
            return text
        codes = _codes(text, self._fold)
        hidden = _hidden(text)
        kept = None if hidden is None else np.flatnonzero(~hidden)
        if kept is not None:
            codes = codes[kept]
        windows = _windows(codes, width)
        maybe = np.flatnonzero(self._pairs[(windows & np.uint64(0xFFFF)).astype(np.intp)])
        found = np.searchsorted(self._grams, windows[maybe])  # the grams are sorted and distinct
        found[found == self._grams.size] = 0
        hits = maybe[self._grams[found] == windows[maybe]]
        if not hits.size:
            return text
        # Covered positions (of the visible characters): [hit, hit + width) for every hit; runs of
        # them become one MARK, spanning the invisible characters inside the run.
        edges = np.zeros(len(codes) + 1, dtype=np.int64)
        edges[hits] += 1  # hits are distinct, so each index is touched once per line
        edges[hits + width] -= 1
        covered = np.cumsum(edges[:-1]) > 0
        change = np.flatnonzero(np.diff(np.concatenate(([False], covered, [False])).astype(np.int8)))
        starts, stops = change[0::2], change[1::2]
        if kept is not None:  # back to positions in the original text
            starts, stops = kept[starts], kept[stops - 1] + 1
        pieces: list[str] = []
        last = 0
        for start, stop in zip(starts.tolist(), stops.tolist(), strict=True):
            pieces.append(text[last:start])
            pieces.append(MARK)
            last = stop
        pieces.append(text[last:])
        return "".join(pieces)

    def holds(self, text: str) -> bool:
        """Whether ``text`` holds the secret or a recognisable fragment of it."""
        return self.text(text) != text

    def optional(self, value: Any) -> str | None:
        """A string field of a response, redacted; None when it is not a string."""
        return self.text(value) if isinstance(value, str) else None

    def diagnostic(self, text: str, width: int = 200) -> str:
        """``text`` for a message: redacted, also of anything that looks like another API key,
        on one line and at most ``width`` characters (only the start of a long text is read)."""
        head = self.text(text[: max(width * 8, 4096)])
        head = _KEY_LIKE.sub(lambda m: m.group(1) + "-****", head)
        return clip(head, width)

    def shown(self, value: Any, width: int = 120) -> str:
        """A JSON value from a response, for a message (redacted, clipped, never raising)."""
        try:
            text = json.dumps(value, ensure_ascii=False)
        except (TypeError, ValueError, RecursionError):
            text = type(value).__name__
        return self.diagnostic(text, width)


def clip(text: str, width: int = 200) -> str:
    """``text`` on one line, cut to ``width`` characters."""
    one = " ".join(text.split())
    return one if len(one) <= width else one[: width - 3] + "..."


def redact_key_like(text: str) -> str:
    """``text`` with anything that looks like an API key (``sk-...``, ``key_...``) blanked."""
    return _KEY_LIKE.sub(lambda m: m.group(1) + "-****", text)


# ---------------------------------------------------------------------------------------------
# The process-wide guard: every key lagrseq reads, for everything it prints or writes
# ---------------------------------------------------------------------------------------------
DEFAULT_KEY_ENV = "OPENAI_API_KEY"
_watched: dict[str, None] = {DEFAULT_KEY_ENV: None}
"""Environment variables that hold a key (ordered, distinct)."""
_remembered: dict[str, None] = {}
"""Secrets handed over in person (the robot's token)."""
_built: dict[str, Redactor] = {}
"""A redactor per secret seen (a handful at most: cleared when it would pass 16)."""


def watch(env_name: str) -> None:
    """Guard the key in environment variable ``env_name`` too (a provider's ``--api-key-env``).
    The variable is read at every :func:`scrub`, so a key set later is guarded as well (the MCAP
    sink asks :func:`active` once for each chunk of queries it writes, not at every query)."""
    _watched[env_name] = None


def remember(secret: str) -> None:
    """Guard ``secret`` too (a token read from a file)."""
    if secret:
        _remembered[secret] = None


def _secrets() -> Iterable[str]:
    environ = os.environ
    for name in _watched:
        value = environ.get(name)
        if value:
            yield value
    yield from _remembered


def _redactors() -> list[Redactor]:
    found = []
    for secret in _secrets():
        if len(secret) < MIN_FRAGMENT or not secret.isascii():
            continue  # a short key is no secret (module docstring); a non-ASCII one is never sent
        redactor = _built.get(secret)
        if redactor is None:
            if len(_built) >= 16:
                _built.clear()
            redactor = _built[secret] = Redactor(secret.strip())
        found.append(redactor)
    return found


def active() -> bool:
    """Whether any key is guarded now (so callers can skip work when none is)."""
    return any(len(secret) >= MIN_FRAGMENT for secret in _secrets())


def scrub(text: str) -> str:
    """``text`` with every guarded key, and every recognisable fragment of one, replaced by
    :data:`MARK` (the module docstring says what is recognised)."""
    for redactor in _redactors():
        text = redactor.text(text)
    return text


def holds_key(text: str) -> bool:
    """Whether ``text`` holds a guarded key or a recognisable fragment of one."""
    return any(redactor.holds(text) for redactor in _redactors())


def scrub_value(value: Any) -> Any:
    """A JSON-like value (dicts, lists, tuples, strings, numbers) with :func:`scrub` applied to
    every string in it, keys of dicts included; returned as is when no key is guarded."""
    redactors = _redactors()
    if not redactors:
        return value

    def clean(item: Any) -> Any:
        if isinstance(item, str):
            for redactor in redactors:
                item = redactor.text(item)
            return item
        if isinstance(item, dict):
            return {clean(k): clean(v) for k, v in item.items()}
        if isinstance(item, (list, tuple)):
            cleaned = [clean(v) for v in item]
            return cleaned if isinstance(item, list) else tuple(cleaned)
        return item

    return clean(value)
