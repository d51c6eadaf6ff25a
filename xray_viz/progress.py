"""Progress bars and messages of the command line, on stderr.

Long jobs - a render band by band, the first compilation of the fast engine's kernels, a mesh
repair or decimation, a walkthrough, a benchmark suite - report their progress to the *current
task* of this module, which the command line opens around them. A task draws a :mod:`tqdm` bar
on stderr, but only when the command line asked for it (:func:`configure`, which ``xray-viz``
calls with ``enabled`` true when stderr is a terminal and ``--quiet`` was not given), and only
once the job has run for :data:`DELAY` seconds (``$XRAY_VIZ_PROGRESS_DELAY`` overrides it), so
that quick jobs print nothing. Otherwise every function here does nothing: the API, the test
suite and the documentation build never draw a bar.

Messages go through :mod:`logging` (the logger ``"xray_viz"``): :func:`setup_logging` gives it
one handler that prints ``xray-viz: message`` (``xray-viz: warning: message`` for warnings) on
stderr, through :func:`tqdm.tqdm.write` so that a bar being drawn is not broken, and routes
Python warnings to it as one line each (the API still *issues* warnings: only the command line
routes them).

Examples
--------
Without :func:`configure`, tasks are silent and cost nothing:

>>> from xray_viz import progress
>>> with progress.task("counting", total=3, unit="step") as t:
...     for _ in range(3):
...         progress.advance()
>>> t.n
3
"""

from __future__ import annotations

import contextlib
import contextvars
import logging
import os
import sys
import threading
import time
import warnings

__all__ = ["DELAY", "configure", "is_enabled", "task", "tracked", "current", "advance", "rows",
           "status", "iterate", "echo", "wrote", "Task", "setup_logging", "LOGGER"]

#: Seconds a task runs before its bar appears (``$XRAY_VIZ_PROGRESS_DELAY`` overrides it).
DELAY = 2.0

#: Name of the package's logger.
LOGGER = "xray_viz"

#: How often the bar of a running task is redrawn, seconds (its elapsed time keeps moving
#: while a band or a compilation takes long).
REFRESH = 0.5

#: Least seconds between two redraws on a step, or the delay if shorter (a delay of 0 - "draw
#: at once, however quick the job" - draws every step).
MININTERVAL = 0.2

_enabled = False
_current: contextvars.ContextVar = contextvars.ContextVar("xray_viz_progress_task", default=None)


def configure(*, enabled: bool) -> None:
    """Turn the progress bars on or off for this process.

    Parameters
    ----------
    enabled : bool
        True draws bars on stderr (the command line passes ``stderr.isatty() and not quiet``).
    """
    global _enabled
    _enabled = bool(enabled)


def is_enabled() -> bool:
    """True when tasks draw bars (see :func:`configure`)."""
    return _enabled


def _delay() -> float:
    raw = os.environ.get("XRAY_VIZ_PROGRESS_DELAY", "").strip()
    try:
        return max(0.0, float(raw)) if raw else DELAY
    except ValueError:
        return DELAY


class Task:
    """One job's progress: a count ``n`` out of ``total`` (None: unknown), and a bar if
    enabled. Made by :func:`task`."""

    def __init__(self, desc: str, *, total=None, unit="it"):
        self.desc, self.total, self.unit, self.n = desc, total, unit, 0
        self._bar = None
        self._stop = None
        if _enabled:
            from tqdm import tqdm

            try:                          # a terminal of unknown size (0 x 0): 80 x 24
                size = os.get_terminal_size(sys.stderr.fileno())
                sized = size.columns > 0 and size.lines > 0
            except (AttributeError, ValueError, OSError):
                sized = False
            fixed = {} if sized else {"ncols": 80, "nrows": 24}
            if total is None:                 # a count and the time so far
                fixed["bar_format"] = "{desc}: {n_fmt}{unit} [{elapsed}{postfix}]"
            delay = _delay()
            self._bar = tqdm(total=total, desc=desc, unit=f" {unit}", file=sys.stderr,
                             leave=False, delay=delay, dynamic_ncols=sized,
                             mininterval=min(MININTERVAL, delay), **fixed)
            self._stop = threading.Event()
            threading.Thread(target=self._tick, daemon=True, name="xray_viz-progress").start()

    def _tick(self):
        bar, stop = self._bar, self._stop
        while not stop.wait(REFRESH):
            if time.time() >= bar.start_t + bar.delay:
                bar.refresh()

    def advance(self, n: int = 1) -> None:
        """Count ``n`` more steps."""
        self.n += n
        if self._bar is not None:
            self._bar.update(n)

    def update_to(self, done: int, total: int | None = None) -> None:
        """Set the count to ``done`` (of ``total``, when given)."""
        if total is not None and total != self.total:
            self.total = total
            if self._bar is not None:
                self._bar.total = total
        self.advance(done - self.n)

    def status(self, text: str | None) -> None:
        """Show ``text`` beside the bar (None: nothing)."""
        if self._bar is not None:
            self._bar.set_postfix_str(text or "", refresh=False)

    def close(self) -> None:
        """Remove the bar (and stop its redraw thread)."""
        if self._bar is not None:
            self._stop.set()
            self._bar.close()
            self._bar = None


@contextlib.contextmanager
def task(desc: str, *, total: int | None = None, unit: str = "it"):
    """Open a task: the current one until the block ends (tasks nest).

    Parameters
    ----------
    desc : str
        What is being done, e.g. ``"rendering"``.
    total : int, optional
        Steps in all, if known.
    unit : str
        What a step is (``"rows"``, ``"figures"``).

    Yields
    ------
    Task
    """
    t = Task(desc, total=total, unit=unit)
    token = _current.set(t)
    try:
        yield t
    finally:
        _current.reset(token)
        t.close()


def current() -> Task | None:
    """The innermost open task, or None."""
    return _current.get()


def advance(n: int = 1) -> None:
    """Count ``n`` steps of the current task (nothing without one)."""
    t = _current.get()
    if t is not None:
        t.advance(n)


def rows(done: int, total: int) -> None:
    """``done`` of ``total`` detector rows rendered: the band callback of a render."""
    t = _current.get()
    if t is not None:
        t.status(None)
        t.update_to(done, total)


def status(text: str | None) -> None:
    """Show ``text`` beside the current task's bar (e.g. ``"compiling"``)."""
    t = _current.get()
    if t is not None:
        t.status(text)


def echo(text: str) -> None:
    """Print ``text`` on stdout, above any bar being drawn."""
    if _enabled:
        from tqdm import tqdm

        tqdm.write(text, file=sys.stdout)
    else:
        print(text, flush=True)


def wrote(path) -> None:
    """Say ``wrote PATH`` on stdout (:func:`echo`) and count a step of the current task."""
    echo(f"wrote {path}")
    advance()


def tracked(desc: str, *, total: int | None = None, unit: str = "it"):
    """Decorate a function so that each call runs as a :func:`task`.

    Examples
    --------
    >>> from xray_viz import progress
    >>> @progress.tracked("adding", unit="steps")
    ... def add(a, b):
    ...     progress.advance()
    ...     return a + b
    >>> add(1, 2)
    3
    """
    import functools

    def decorate(func):
        @functools.wraps(func)
        def run(*args, **kwargs):
            with task(desc, total=total, unit=unit):
                return func(*args, **kwargs)
        return run
    return decorate


def iterate(iterable, desc: str, *, total: int | None = None, unit: str = "it"):
    """Iterate over ``iterable`` as a task of that many steps.

    Examples
    --------
    >>> from xray_viz import progress
    >>> [x * x for x in progress.iterate(range(3), "squares")]
    [0, 1, 4]
    """
    if total is None and hasattr(iterable, "__len__"):
        total = len(iterable)
    with task(desc, total=total, unit=unit) as t:
        for item in iterable:
            yield item
            t.advance()


# --------------------------------------------------------------------------------------------
# Messages


class _Handler(logging.Handler):
    """``xray-viz: message`` on the stderr of the moment, around any bar being drawn."""

    def emit(self, record):
        try:
            msg = self.format(record)
            if record.levelno >= logging.WARNING:
                msg = f"xray-viz: {record.levelname.lower()}: {msg}"
            elif record.levelno >= logging.INFO:
                msg = f"xray-viz: {msg}"
            else:
                msg = f"xray-viz: debug: {record.name}: {msg}"
            msg = " ".join(msg.splitlines())
            if _enabled:
                from tqdm import tqdm

                tqdm.write(msg, file=sys.stderr)
            else:
                print(msg, file=sys.stderr, flush=True)
        except Exception:  # pragma: no cover - logging's own contract
            self.handleError(record)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Python warnings as one line through the ``xray_viz`` logger."""
    logging.getLogger(f"{LOGGER}.warnings").warning("%s", message)


@contextlib.contextmanager
def setup_logging(level: int = logging.INFO):
    """Route the ``xray_viz`` logger and Python warnings to stderr, for the block.

    Parameters
    ----------
    level : int
        The logger's level: ``logging.INFO`` by default (notices and warnings),
        ``logging.DEBUG`` with ``-v``, ``logging.WARNING`` with ``-q``.

    Warnings are shown (each once per place, Python's default) as ``xray-viz: warning:
    message``; below ``logging.WARNING`` (``-qq``) they are not shown.
    """
    logger = logging.getLogger(LOGGER)
    handler = _Handler()
    saved = logger.level, logger.propagate
    logger.addHandler(handler)
    logger.setLevel(level)
    logger.propagate = False
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        try:
            yield logger
        finally:
            logger.removeHandler(handler)
            logger.setLevel(saved[0])
            logger.propagate = saved[1]
