"""Text from outside (file names, model paths, plugin descriptions, host names, server replies)
made safe to print: :func:`printable` escapes what could forge a line or drive the terminal, and
:func:`safe_streams` makes stdout and stderr escape what their encoding cannot write.

A file name is bytes on POSIX: a name that is not UTF-8 comes into Python with lone surrogates
(``os.fsdecode``), which no encoder writes, and a name may hold a newline (a forged extra line of
output) or an ANSI escape (colours, a cleared screen, a rewritten line). Every print of such text
goes through :func:`printable`, which keeps ordinary text (any script, emoji) exactly and writes
the rest as Python-style escapes: ``\\n``, ``\\t``, ``\\x1b``, ``\\u202e`` (bidi overrides and
other format characters), and a byte of a non-UTF-8 name as ``\\xff``.
"""

from __future__ import annotations

import contextlib
import stat
import sys
import unicodedata

_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t", "\\": "\\\\"}
_ESCAPED_CATEGORIES = frozenset(("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp"))


def _escape(char: str) -> str:
    named = _NAMED.get(char)
    if named is not None:
        return named
    code = ord(char)
    if 0xDC80 <= code <= 0xDCFF:  # a byte of a non-UTF-8 file name (os.fsdecode's surrogateescape)
        return f"\\x{code - 0xDC00:02x}"
    if code <= 0xFF:
        return f"\\x{code:02x}"
    return f"\\u{code:04x}" if code <= 0xFFFF else f"\\U{code:08x}"


def printable(text: str) -> str:
    """``text`` on one line with nothing that acts on a terminal: control characters (newlines,
    ANSI escapes), format characters (bidi overrides, zero-width ones), line and paragraph
    separators, lone surrogates (the bytes of a non-UTF-8 file name), private-use and unassigned
    code points are written as escapes; a backslash is doubled only where the text is changed
    (so an ordinary Windows path prints as it is)."""
    if text.isascii() and text.isprintable():
        return text
    if text.isprintable() and not any(0xD800 <= ord(c) <= 0xDFFF for c in text):
        return text  # isprintable is False for Cc, Cf, Zl, Zp, Zs other than space, Cs, Co, Cn
    pieces = []
    for char in text:
        if char == "\\" or unicodedata.category(char) in _ESCAPED_CATEGORIES:
            pieces.append(_escape(char))
        else:
            pieces.append(char)
    return "".join(pieces)


def safe_streams() -> None:
    """Make ``sys.stdout`` and ``sys.stderr`` write what their encoding cannot as escapes
    (``PYTHONIOENCODING=ascii``, a C locale) instead of raising UnicodeEncodeError."""
    for stream in (sys.stdout, sys.stderr):
        reconfigure = getattr(stream, "reconfigure", None)
        if reconfigure is not None:
            with contextlib.suppress(Exception):  # a replaced stream that takes no such option
                reconfigure(errors="backslashreplace")


def shown(text: object) -> str:
    """Outside text for one line of a terminal or a message: every guarded API key blanked
    (:func:`lagrseq.keys.scrub`), then :func:`printable`."""
    from lagrseq.keys import scrub

    return printable(scrub(str(text)))


# ---------------------------------------------------------------------------------------------
# One escaper per medium (every cell of outside text a report writes goes through one of these)
# ---------------------------------------------------------------------------------------------
def terminal(text: object, width: int | None = None) -> str:
    """Outside text for a terminal: :func:`shown` (keys blanked, controls written as escapes),
    cut to ``width`` characters with an ellipsis when given."""
    return cut(shown(text), width)


def cut(text: str, width: int | None) -> str:
    """``text`` at most ``width`` characters, a longer one ending in ``…`` (None: as it is)."""
    if width is None or len(text) <= width:
        return text
    return text[: max(width - 1, 0)] + "…"


def markdown_cell(text: object) -> str:
    """Outside text for a Markdown table cell: keys blanked (before anything is escaped, so an
    escaped zero-width space cannot hide one), HTML escaped (``<script>`` is shown, never run),
    ``|`` escaped (it would end the cell), controls and line breaks written as escapes."""
    import html

    return html.escape(shown(text), quote=False).replace("|", "\\|")


def markdown_text(text: object) -> str:
    """Outside text for a line of Markdown prose (a heading, a list item): keys blanked, HTML
    escaped, controls written as escapes (a ``|`` outside a table needs nothing)."""
    import html

    return html.escape(shown(text), quote=False)


def html_text(text: object) -> str:
    """Outside text for HTML (an element's text or an attribute's value), keys blanked."""
    import html

    from lagrseq.keys import scrub

    return html.escape(scrub(str(text)), quote=True)


_FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def csv_cell(value: object) -> object:
    """A CSV cell that a spreadsheet will not run as a formula: text starting with ``=``, ``+``,
    ``-``, ``@``, a tab or a carriage return gets a leading ``'`` (OWASP's advice), unless it is a
    plain number (``-0.5``, ``+3``) or a lone ``-``; keys are blanked; anything that is not text
    is returned as it is."""
    if isinstance(value, str):
        from lagrseq.keys import scrub

        value = scrub(value)
    if not isinstance(value, str) or not value.startswith(_FORMULA_STARTS) or value == "-":
        return value
    try:
        float(value)
    except ValueError:
        return "'" + value
    return value


def kind_of(mode: int) -> str:
    """What a stat mode is, in words."""
    for test, name in (
        (stat.S_ISREG, "a file"), (stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
    ):
        if test(mode):
            return name
    return "not a regular file"
