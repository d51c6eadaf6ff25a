"""Errors raised by xray_viz.

Every error subclasses a built-in exception (``ValueError``, ``FileNotFoundError``) so that
``except ValueError`` works, and also :class:`XrayVizError`, so that the command line can tell
a user's bad input (printed as one line) from a bug (a traceback).
"""

from __future__ import annotations

import re


class XrayVizError(Exception):
    """Base class of every error that describes bad input rather than a bug."""


class SceneError(XrayVizError, ValueError):
    """A scene file or scene description is malformed: unknown key, wrong type, bad value."""


class MeshError(XrayVizError, ValueError):
    """A mesh is missing, unreadable, empty, non-finite, or cannot be traced correctly."""


class MaterialError(XrayVizError, ValueError):
    """A material name, formula or density is unknown or invalid."""


class SpectrumError(XrayVizError, ValueError):
    """An X-ray spectrum specification is invalid."""


class OutputError(XrayVizError, ValueError):
    """An output file name or format is not supported."""


class EngineError(XrayVizError, RuntimeError):
    """An engine produced a result that breaks an invariant of the physics (a negative or
    non-finite path length, a transmission above 1): refused rather than written, never a
    silent wrong image. A bug: the message says how to report it and which engine to use."""


class SceneFileNotFoundError(XrayVizError, FileNotFoundError):
    """A file named by the user (scene, mesh, spectrum) does not exist."""


class ScatterModelWarning(UserWarning):
    """A scene outside what a fast scatter model was fitted for (the message names the
    quantity and its value): its scatter is an extrapolation
    (:mod:`xray_viz.scatter_kernel`)."""


class CacheWarning(UserWarning):
    """A folder of the disk cache cannot be written: that kind of data is not cached (the
    results are the same, computed again)."""


class WriteInterrupted(SystemExit):
    """A termination signal (SIGTERM, SIGHUP) arrived while an output file was being written.

    Raised by :func:`xray_viz.output.atomic_write` after it removed its temporary file; the
    previous file at the target, if any, is untouched. A ``SystemExit`` with the status a
    process killed by the signal reports, ``128 + signum``, so an uncaught one ends the program
    as the signal would have (but after the clean-up); ``except Exception`` does not catch it.
    """

    def __init__(self, message: str, signum: int):
        super().__init__(128 + int(signum))
        self.message = message
        self.signum = int(signum)

    def __str__(self) -> str:
        return self.message


def excerpt(text, limit: int = 40) -> str:
    r"""A short, escaped quotation of untrusted text (a line of a user's file) for a message.

    The first ``limit`` characters, quoted and escaped as :func:`repr` does (control
    characters, newlines and other unprintable characters become ``\x01``, ``\n``, ...;
    printable non-ASCII text stays readable), followed by ``...`` and the full length when
    the text was cut. Bytes are quoted as bytes (``b'...'``). The result is one line of bounded
    length (at most ``10 * limit + 30`` characters, the longest escape being ``\U0001xxxx``),
    whatever the input.

    Examples
    --------
    >>> excerpt("0.5x")
    "'0.5x'"
    >>> excerpt("A" * 100 + "\x1b[31m", limit=5)
    "'AAAAA'... (105 characters)"
    >>> excerpt("tab\there")
    "'tab\\there'"
    """
    if not isinstance(text, (str, bytes)):
        text = str(text)
    if len(text) <= limit:
        return repr(text)
    unit = "bytes" if isinstance(text, bytes) else "characters"
    return f"{text[:limit]!r}... ({len(text)} {unit})"


#: A quoted stretch of a message: 'text', "text" or `text` (or unterminated, to the end).
_QUOTED = re.compile(r"""'([^']*)(?:'|$)|"([^"]*)(?:"|$)|`([^`]*)(?:`|$)""")


def reader_reason(exc, limit: int = 160) -> str:
    r"""A file reader's error message as part of one line, with every quoted stretch replaced
    by ``'...'``: readers quote the line they choked on, and the file may be any file a scene
    names (someone's private file), so what a file holds is never echoed back.

    Examples
    --------
    >>> reader_reason(ValueError("could not convert string to float: 'FAKESECRET-1'\n"))
    "could not convert string to float: '...'"
    """
    text = one_line(exc, limit=4000)
    text = _QUOTED.sub(lambda m: f"{m.group(0)[0]}...{m.group(0)[0]}", text)
    return one_line(text, limit=limit)


def one_line(text, limit: int = 200) -> str:
    r"""Another library's error message made safe to print as part of one line.

    Runs of white space (newlines, tabs) become one space, other unprintable characters are
    escaped as :func:`repr` escapes them, and the result is cut to ``limit`` characters with
    ``...``: a reader's message that quotes a whole line of a file (or a multi-line traceback
    embedded in an exception) cannot flood the terminal or move its cursor.

    Examples
    --------
    >>> one_line("bad token\n  at line 3:\x07 " + "x" * 300, limit=30)
    'bad token at line 3:\\x07 xx...'
    """
    if isinstance(text, bytes):
        text = text.decode("utf-8", errors="backslashreplace")
    text = " ".join(str(text).split())
    text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return text if len(text) <= limit else text[:limit - 3].rstrip() + "..."
