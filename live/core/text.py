"""Text from untrusted places made safe: for a terminal (``printable``) and as a file name
(``safe_filename``).

Stream names, metadata and file contents come from files anyone can write. Printed as they are,
an escape sequence in a stream name retitles or clears the user's terminal and a bidi override
reverses what the line says; used as a path, ``cam/../../x`` writes outside the output folder.
"""

from __future__ import annotations

import hashlib
import string
import unicodedata

#: Unicode categories written as escapes by ``printable``: controls (ESC, CR, DEL, C1), formatting
#: characters (bidi overrides, zero-width joiners), lone surrogates, line and paragraph separators.
UNPRINTABLE_CATEGORIES = frozenset({"Cc", "Cf", "Cs", "Zl", "Zp"})
#: Characters ``safe_filename`` keeps as they are; everything else is percent-encoded.
FILENAME_CHARS = frozenset(string.ascii_letters + string.digits + "-_.")
#: Longest file name ``safe_filename`` returns, in characters (= bytes: the result is ASCII).
MAX_FILENAME_CHARS = 120


def _escape(ch: str) -> str:
    code = ord(ch)
    if code < 0x100:
        return f"\\x{code:02x}"
    if code < 0x10000:
        return f"\\u{code:04x}"
    return f"\\U{code:08x}"


def printable(text: object, max_chars: int = 300) -> str:
    """``text`` as one inert line for a terminal: every control or formatting character (ESC,
    CR, LF, DEL, C1 controls, bidi overrides, zero-width characters, lone surrogates) written as a
    Python-style escape (``\\x1b``, ``\\u202e``), and text longer than ``max_chars`` cut with
    "...". Bytes are decoded as UTF-8 first (undecodable bytes escaped)."""
    if isinstance(text, bytes | bytearray):
        text = bytes(text).decode("utf-8", "backslashreplace")
    s = str(text)
    out = "".join(_escape(c) if unicodedata.category(c) in UNPRINTABLE_CATEGORIES else c for c in s)
    if len(out) > max_chars:
        out = out[: max(0, max_chars - 3)] + "..."
    return out


def printable_text(text: str, keep: str = "\n\t") -> str:
    """``text`` with every control or formatting character escaped as in ``printable``, except
    those in ``keep`` (line feeds and tabs: the layout of a command's output), and never cut."""
    return "".join(_escape(c) if c not in keep and unicodedata.category(c) in UNPRINTABLE_CATEGORIES else c
                   for c in text)


class PrintableWriter:
    """A text stream that writes everything through ``printable_text``: a command's output can
    quote stream names and metadata from a file without sending its escape sequences to the
    terminal. ``keep``: the control characters let through (a progress bar on stderr needs "\r").
    Everything else (flush, isatty, encoding, buffer) is the wrapped stream's."""

    def __init__(self, stream, keep: str = "\n\t"):
        self._stream = stream
        self._keep = keep

    def write(self, text: str) -> int:
        self._stream.write(printable_text(text, self._keep))
        return len(text)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def safe_filename(name: str, max_chars: int = MAX_FILENAME_CHARS) -> str:
    """A file name (one path component) for ``name``, e.g. a stream name from a session.

    ASCII letters, digits, ``-``, ``_`` and ``.`` are kept; every other byte of the UTF-8 text
    (``/``, ``\\``, ``%``, spaces, controls, non-ASCII) becomes ``%XX``, as in URLs, and so does a
    leading ``.`` (no hidden files, no ``.`` or ``..``). The mapping is one-to-one, so different
    names never share a file: ``oak`` stays ``oak``, ``cam/../../x`` becomes ``cam%2F..%2F..%2Fx``,
    the empty name ``%``. A result longer than ``max_chars`` is cut and ends in ``~`` and 16 hex
    digits of the name's SHA-256 (still one-to-one short of a hash collision)."""
    if max_chars < 24:
        raise ValueError(f"max_chars must be at least 24, got {max_chars}")
    raw = str(name).encode("utf-8", "surrogatepass")
    parts = []
    for i, b in enumerate(raw):
        ch = chr(b)
        keep = ch in FILENAME_CHARS and not (i == 0 and ch == ".")
        parts.append(ch if keep else f"%{b:02X}")
    out = "".join(parts) or "%"
    if len(out) > max_chars:
        digest = hashlib.sha256(raw).hexdigest()[:16]
        head = out[: max_chars - 17]
        cut = head.rfind("%")
        if cut >= len(head) - 2:  # do not leave half of a %XX escape
            head = head[:cut]
        out = f"{head}~{digest}"
    return out
