"""Compiling the library's numba kernels: one module for every module of kernels.

A module of kernels (:mod:`xray_viz.tracing._raster`, :mod:`xray_viz.meshes._check_kernels`,
:mod:`xray_viz._gradient_kernels`) defines its kernels with ``@njit(cache=True, nogil=True)`` and lists them, with the one
explicit signature each is compiled for, in a :class:`KernelSet` named ``KERNELS``. The set
compiles each kernel on its first use (or loads it from numba's disk cache,
:mod:`xray_viz.tracing._numba_cache`) and then forbids numba to compile another
specialisation: a caller passing other types gets numba's "no matching definition" error, not
a silent second compile. The code that calls the kernels asks the set for them by name
(``KERNELS.kernel("_raster_bands")``): plain functions, no rebinding of module globals.

On a cold cache a process can hand the compiles to background processes, which fill the cache
while it does something else (:meth:`KernelSet.prepare`: the command line starts the costliest
kernels of the scene's likely paths while it loads the scene, and waits for each when it first
needs it; :meth:`KernelSet.fill_cache`: one detached low-priority process for kernels nothing
waits for). Every background process runs :data:`WORKER`.
"""

from __future__ import annotations

import contextlib
import os
import threading

from xray_viz.tracing import _numba_cache

#: The background compile: ``argv`` is the package's folder, the kernels' module, a marker
#: file to remove at the end ('' for none), the niceness to add before the others, the urgent
#: kernels (those the parent waits for), ``--``, and the others, compiled at that lower
#: priority (``nice``) so that they take no processor from the parent. Each kernel is named on the output once it is cached (a closed
#: output - the parent gone - does not stop it). It imports numba and the kernels' module
#: only: ``xray_viz`` and its sub-packages are bare packages here (their ``__init__``, which
#: imports the whole library, is not run; the kernels' module and file are the same, so they
#: are cached under the same keys).
WORKER = """\
import importlib, os, sys, types, warnings
warnings.simplefilter('ignore')
root, module, marker, nice = sys.argv[1:5]
package = module.rpartition('.')[0]
for name in dict.fromkeys(('xray_viz', 'xray_viz.tracing', package)):
    m = types.ModuleType(name)
    m.__path__ = [os.path.join(root, *name.split('.')[1:])]
    sys.modules[name] = m
try:
    kernels = importlib.import_module(module).KERNELS
    for n in sys.argv[5:]:
        if n == '--':
            os.nice(int(nice)) if hasattr(os, 'nice') else None
            continue
        kernels.kernel(n)
        try:
            print(n, flush=True)
        except OSError:
            pass
finally:
    if marker:
        try:
            os.unlink(marker)
        except OSError:
            pass
"""


@contextlib.contextmanager
def opt_level(level):
    """Inside: numba compiles at LLVM optimisation ``level`` (its ``config.OPT``), unless
    ``level`` is None or the environment sets ``NUMBA_OPT`` (the user's choice wins)."""
    if level is None or "NUMBA_OPT" in os.environ:
        yield
        return
    from numba.core import config

    old, config.OPT = config.OPT, config._OptLevel(level)
    try:
        yield
    finally:
        config.OPT = old


class KernelSet:
    """The kernels of one module, each with its one explicit signature.

    Parameters
    ----------
    module : str
        The kernels' module (imported by the background processes, which compile through
        its ``KERNELS``).
    kernels : dict
        Kernel name -> numba dispatcher (``@njit(cache=True)``).
    signatures : dict
        Kernel name -> the tuple of numba argument types of its one specialisation.
    paths : dict, optional
        Named groups of kernels (an engine's code paths): name -> tuple of kernel names;
        default one group ``"all"``.
    costs : dict, optional
        Tuple of kernel names -> compile CPU seconds (kernels of one tuple share helpers and
        go to the same background process); default 1 each.
    worker_opt : int, optional
        LLVM optimisation level of the background processes' compiles (``NUMBA_OPT``), unless
        the environment sets one; also that of the kernels :meth:`prepare` leaves to this
        process (the cache does not record the level).
    head : float, optional
        Seconds of compiling the background process of :meth:`prepare` takes on beyond this
        process's share (its head start while this process does something else).
    """

    def __init__(self, module: str, kernels: dict, signatures: dict, *, paths=None,
                 costs=None, worker_opt=None, head: float = 0.0):
        self.module = module
        self.kernels = dict(kernels)
        self.signatures = dict(signatures)
        self.paths = dict(paths) if paths is not None else {"all": tuple(signatures)}
        self.costs = dict(costs) if costs is not None else {(n,): 1.0 for n in signatures}
        self.worker_opt = worker_opt
        self.head = head
        #: Kernels compiled or loaded in this process.
        self.ready: set = set()
        self._lock = threading.Lock()
        #: Kernel name -> the background process compiling it into numba's cache.
        self.workers: dict = {}
        #: Kernel names each worker has said are cached (by ``id`` of the process).
        self._done: dict = {}
        #: Kernels :meth:`prepare` left to this process, compiled at ``worker_opt``.
        self.mine: set = set()
        #: Kernels whose worker this process waits for at exit (when it used a kernel).
        self.urgent: set = set()
        self._detached: list = []
        self._atexit_set = False

    def kernel(self, name: str):
        """The dispatcher of kernel ``name``, with its one specialisation compiled or loaded
        (after waiting for a background process compiling it)."""
        disp = self.kernels[name]
        if name not in self.ready:
            with self._lock:
                if name not in self.ready:
                    if name in self.workers:
                        _numba_cache.needs_background()   # the compile notice, if not said
                    self._wait(name)
                    with opt_level(self.worker_opt if name in self.mine else None):
                        disp.compile(self.signatures[name])
                    disp.disable_compile()
                    self.ready.add(name)
        return disp

    def names(self, paths=None) -> list:
        """The kernels of ``paths`` (keys of :attr:`paths`; default all), each once."""
        names = []
        for p in (self.paths if paths is None else paths):
            names += [n for n in self.paths[p] if n not in names]
        return names

    def compile(self, paths=None) -> list:
        """Compile (or load from the cache) the kernels of ``paths`` in this thread; returns
        their names."""
        names = self.names(paths)
        for name in names:
            self.kernel(name)
        return names

    def is_cached(self, name: str) -> bool:
        """Whether numba's cache holds kernel ``name``'s specialisation."""
        disp = self.kernels[name]
        is_cached = getattr(getattr(disp, "_cache", None), "is_cached", None)
        return bool(is_cached and is_cached(self.signatures[name], disp.targetctx))

    def is_ready(self, paths=None) -> bool:
        """Whether using every kernel of ``paths`` costs no compilation (compiled in this
        process or in numba's cache)."""
        return all(n in self.ready or self.is_cached(n) for n in self.names(paths))

    def _shared_cache(self):
        """The :class:`~xray_viz.tracing._numba_cache.KernelCache` of the kernels, or None when
        there is no cache to share compiled kernels through."""
        cache = getattr(next(iter(self.kernels.values())), "_cache", None)
        return cache if isinstance(cache, _numba_cache.KernelCache) else None

    def _start(self, names: list, *, marker: str = "", nice: int = 10, env=None,
               detached: bool = False):
        import subprocess
        import sys

        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        proc = subprocess.Popen([sys.executable, "-c", WORKER, root, self.module, marker,
                                 str(int(nice)), *names], stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL if detached else subprocess.PIPE,
                                stderr=subprocess.DEVNULL, text=True, env=env,
                                start_new_session=detached)
        # kept referenced for the life of this process: a Popen collected while its process
        # still compiles warns (ResourceWarning), e.g. once _wait has its kernel
        self._detached.append(proc)
        return proc

    def fill_cache(self, *, nice: int = 10) -> bool:
        """Start one detached background process compiling every kernel numba's cache lacks,
        ``nice`` added to its niceness, unless they are all ready, another process is already compiling
        them into the same cache, or there is no cache; returns whether one started. Nothing
        in this process waits for it (its kernels are for later processes).

        One compiling process per cache: a marker file beside the cache files, taken with
        ``O_EXCL``, removed by the process when it ends; one older than 10 minutes is from a
        process that died.
        """
        import time

        cache = self._shared_cache()
        if self.is_ready() or cache is None:
            return False
        marker = os.path.join(cache._cache_path, self.module.replace(".", "-") + ".compiling")
        try:
            os.makedirs(cache._cache_path, exist_ok=True)
            if os.path.exists(marker) and time.time() - os.path.getmtime(marker) > 600:
                os.unlink(marker)
            os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
        except OSError:
            return False
        names = [n for n in self.signatures if not self.is_cached(n)]
        self._start(["--", *names], marker=marker, nice=nice, detached=True)
        return True

    def prepare(self, paths=None, *, workers: int | None = None, first=None) -> list:
        """Start compiling the kernels of ``paths`` that numba's cache lacks in background
        processes; returns their names (``xray-viz render`` calls it for the fast engine's
        kernels, :data:`xray_viz.tracing._raster.KERNELS`, before it loads the scene).

        By default one background process is started, and this process keeps a share of the
        urgent kernels (those of the paths ``first``; default all) to compile itself when it
        first needs them: the background process takes the costliest (by :attr:`costs`)
        until its share is the larger by :attr:`head`. With ``workers`` given, every kernel
        goes to that many background processes, shared out by cost. A background process
        compiles its urgent kernels first, then the others at a lower priority, and last this
        process's share, so that the cache ends up with every kernel. At exit this process
        waits for a background process still compiling an urgent kernel if it used a kernel,
        and stops them if it used none. Nothing starts when every kernel is cached, when only
        kernels outside ``first`` are missing, or when there is no cache to share them
        through.
        """
        names = [n for n in self.names(paths)
                 if n not in self.ready and n not in self.workers and n not in self.mine]
        missing = [n for n in names if not self.is_cached(n)]
        if not missing or self._shared_cache() is None:
            return []
        urgent = set(self.names(first)) if first is not None else set(missing)
        if not urgent.intersection(missing):
            # only other kinds of scene lack kernels: an earlier process's worker is most
            # likely compiling them now; they are compiled here if needed after all
            return []
        units = [([n for n in unit if n in missing], cost) for unit, cost in
                 sorted(self.costs.items(), key=lambda kv: -kv[1])]      # costliest first
        kept = []                            # this process's share of the urgent kernels
        if workers is None:
            groups = [[]]
            ours = [(u, c) for u, c in units if u and u[0] in urgent]
            share, load = (sum(c for _, c in ours) + self.head) / 2, 0.0
            for unit, cost in ours:
                if not groups[0] or load + cost <= share + 1e-9:
                    groups[0] += unit
                    load += cost
                else:
                    kept += unit
            groups[0] += [n for u, _ in units for n in u if n not in urgent]
        else:
            n_workers = max(1, min(workers, len(missing)))
            groups = [[] for _ in range(n_workers)]
            load = [0.0] * n_workers
            for pass_ in (True, False):          # the urgent kernels first, shared by cost
                for unit, cost in units:
                    todo = [n for n in unit if (n in urgent) == pass_]
                    if todo:
                        k = load.index(min(load))
                        groups[k] += todo
                        load[k] += cost
        self.urgent.update(n for n in missing if n in urgent and n not in kept)
        self.mine.update(kept)
        need = ([n for n in self.names(first) if n in self.urgent] if first is not None
                else missing)
        _numba_cache.background_compile(self.kernels[missing[0]])
        env = dict(os.environ)
        if self.worker_opt is not None:
            env.setdefault("NUMBA_OPT", str(self.worker_opt))     # the user's choice wins
        for group in groups:
            if group:
                urgent_first = [n for n in need if n in group]      # in the order of first use
                rest = [n for n in group if n not in urgent_first] + kept
                kept = []                    # (to the first background process only)
                proc = self._start([*urgent_first, *(["--", *rest] if rest else [])], env=env)
                for n in group:
                    self.workers[n] = proc
        if not self._atexit_set:
            import atexit

            atexit.register(self._finish_workers)
            self._atexit_set = True
        return missing

    def _wait(self, name: str) -> None:
        """Wait until the worker compiling ``name`` says it is cached (or ends): then it is
        loaded from the cache (compiled here if the worker failed)."""
        proc = self.workers.pop(name, None)
        if proc is None:
            return
        done = self._done.setdefault(id(proc), set())
        while name not in done:
            line = proc.stdout.readline()
            if not line:
                proc.wait()
                break
            done.add(line.strip())

    def _finish_workers(self) -> None:
        """At exit: stop the workers if this process used no kernel; else wait for those
        still compiling an urgent kernel and leave the others to finish alone."""
        if not self.ready:
            for proc in {id(p): p for p in self.workers.values()}.values():
                proc.terminate()
                proc.wait()
        else:
            for name in [n for n in self.workers if n in self.urgent]:
                self._wait(name)
        self.workers.clear()
