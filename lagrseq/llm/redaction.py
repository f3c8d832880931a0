"""Keeping the API key out of everything a server sends back.

A server may echo the key it was sent: in the answer text, the ``model`` field, an error message,
a header, whole or in part (without its ``sk-`` prefix, upper-cased, split over two fields). Every
string that came back from a server passes through :meth:`Redactor.text` before it is put in an
answer, a store, an exception message or a callback.

What counts as the key: the whole key, and every run of the text in which each window of
:data:`MIN_FRAGMENT` characters is a substring of the key (so every substring of the key at least
that long, and overlapping chains of them). Matching ignores ASCII case. ``MIN_FRAGMENT`` is 8:
API keys are random base-62 strings (OpenAI's are ``sk-proj-`` and about 160 characters, vLLM's
whatever the operator chose), and 8 random base-62 characters carry about 48 bits, so an 8-character
window of a key turning up in an innocent answer by chance is negligible, while any echo long
enough to be recognised as part of the key (and to help anyone guess it) is caught. Pieces shorter
than 8 characters are not recognisable and are left; a key split into two fields leaves pieces of
at least half its length, which are caught. A key shorter than 8 characters is redacted only whole
and only in its own case (such a key, ``EMPTY`` or ``ollama`` for a local server, is no secret
and is easily mistaken for ordinary words, which should not be blanked out of answers).

The scan is linear in the text: every window is packed into one 64-bit integer (8 characters of
8 bits: the key is printable ASCII and anything else maps to a code no key has) and looked up among
the key's windows with numpy, so a 4 MiB body takes tens of milliseconds whatever it holds.
"""

from __future__ import annotations

import json
import re
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
    wide = np.frombuffer(text.encode("utf-32-le", "surrogatepass"), dtype="<u4")
    if fold:
        wide = np.where((wide >= 65) & (wide <= 90), wide + 32, wide)
    return np.minimum(wide, _NOT_ASCII).astype(np.uint8)


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
        """``text`` with every run made of the secret's windows replaced by :data:`MARK`."""
        width = self._width
        if not self._grams.size or len(text) < width:
            return text
        windows = _windows(_codes(text, self._fold), width)
        maybe = np.flatnonzero(self._pairs[(windows & np.uint64(0xFFFF)).astype(np.intp)])
        found = np.searchsorted(self._grams, windows[maybe])  # the grams are sorted and distinct
        found[found == self._grams.size] = 0
        hits = maybe[self._grams[found] == windows[maybe]]
        if not hits.size:
            return text
        # Covered positions: [hit, hit + width) for every hit; runs of them become one MARK.
        edges = np.zeros(len(text) + 1, dtype=np.int64)
        edges[hits] += 1  # hits are distinct, so each index is touched once per line
        edges[hits + width] -= 1
        covered = np.cumsum(edges[:-1]) > 0
        change = np.flatnonzero(np.diff(np.concatenate(([False], covered, [False])).astype(np.int8)))
        pieces: list[str] = []
        last = 0
        for start, stop in zip(change[0::2].tolist(), change[1::2].tolist(), strict=True):
            pieces.append(text[last:start])
            pieces.append(MARK)
            last = stop
        pieces.append(text[last:])
        return "".join(pieces)

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
