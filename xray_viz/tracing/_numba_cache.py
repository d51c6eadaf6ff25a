"""Where numba caches the fast engine's compiled kernels, and what happens when it cannot.

The fast engine's kernels (:mod:`xray_viz.tracing._raster`, ``@njit(cache=True)``) are
compiled by numba on first use (a few seconds) and cached on disk, so that later processes load them
in a fraction of a second. ``_raster`` imports this module before its kernels are defined; this
module wraps numba's ``Dispatcher.enable_caching`` (what ``cache=True`` calls when a function is
decorated) so that every cached numba function of xray_viz gets the cache described here; other
packages' numba functions are left to numba.

Where kernels are cached, decided when each kernel is decorated (``_raster`` imported): the
first usable directory of

1. ``$NUMBA_CACHE_DIR`` (``numba.config.CACHE_DIR``, read by numba when it is imported), if set;
2. the package's own ``__pycache__`` beside ``_raster.py``;
3. numba's user-wide cache, ``$XDG_CACHE_HOME/numba`` or ``~/.cache/numba``;
4. a private per-user directory ``<tmp>/xray_viz-numba-<uid>``, ``<tmp>`` being
   :func:`tempfile.gettempdir` (``$TMPDIR``, else ``/tmp``, ...). It is created with mode 0700
   and used only if it is a directory owned by the user and writable by nobody else (cached
   kernels are machine code that gets loaded and run);
5. nowhere: kernels are compiled again by every process.

Places 1-3 are numba's own, in numba's order (``numba.core.caching``: the user-provided, in-tree
and user-wide locators); "usable" is numba's test: the directory exists or can be made, and a
file can be written in it. In 1, 3 and 4 the kernels sit in a sub-directory named after the
package's folder (numba's scheme), so several installs can share one place. A read-only install
(a system or container image, a shared environment) with an unwritable home thus caches in
``<tmp>``. When the cache is not where numba alone would have put it (4, 5, or an unusable
``$NUMBA_CACHE_DIR``), one :class:`KernelCacheWarning` (one line) says where it is; set
``NUMBA_CACHE_DIR`` to choose the place. ``NUMBA_CACHE_LOCATOR_CLASSES``, if set, replaces the
list of places 1-4 as it does for numba. :func:`cache_path` tells where a kernel is cached, and
:func:`on_first_compile` when one is compiled rather than loaded (the CLI's notice).

numba keys a cached kernel by its own source file only: a kernel that calls (and inlines) a
numba function of another module would be loaded stale after that function changed. The key
of every cached function of xray_viz therefore also holds ``callee_digest``, the SHA-256
of the source files of the xray_viz numba functions it calls, directly or not, in other files
(e.g. the tie rule of ``xray_viz.tracing._primitives``, inlined into the kernels of
``_raster``, ``_gradient_kernels`` and the Monte Carlo).

What is read back is checked: every data file (``.nbc``) written here starts with a header and
the SHA-256 of its content, so a truncated, garbled or foreign file is detected before numba
unpickles it or LLVM loads its machine code. An index (``.nbi``) or data file that cannot be read
or rebuilt into a kernel gives one warning naming it, and the kernel is compiled again and its
files rewritten; a cache that cannot be written gives one warning and the kernel stays compiled
for the process. A broken cache never stops a render. Deleting the cache is always safe.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
import pickle
import stat
import tempfile
import threading
import types
import warnings

from numba.core import caching, config, dispatcher, event


class KernelCacheWarning(UserWarning):
    """The fast engine's kernels are cached somewhere unusual, or a kernel cache file was bad."""


#: Modules (by name prefix) whose cached numba functions get the cache of this module.
PACKAGE = "xray_viz."
#: First bytes of every data file written here; the SHA-256 of the rest follows.
MAGIC = b"xray_viz kernel cache v1\n"
_DIGEST = hashlib.sha256().digest_size

_lock = threading.Lock()
_warned: set = set()
#: Why the per-user temporary directory was refused, if it was (for the warning).
_refused: dict[str, str] = {}


def _warn_once(key, message: str) -> None:
    with _lock:
        if key in _warned:
            return
        _warned.add(key)
    # Line 0 of this file: Python then prints the warning as one line, without a source line
    # that would mean nothing to the user (the CLI prints "xray-viz: warning: ..." anyway).
    warnings.warn_explicit(" ".join(message.split()), KernelCacheWarning, __file__, 0,
                           module=__name__)


def _why(exc: BaseException) -> str:
    """One line for an exception: its type and message (LLVM's may span several lines)."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def user_temp_root() -> str:
    """The per-user directory in the temporary directory: ``<tmp>/xray_viz-numba-<uid>``.

    Raises
    ------
    FileNotFoundError
        When no temporary directory is writable (:func:`tempfile.gettempdir`).
    """
    user = os.getuid() if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
    return os.path.join(tempfile.gettempdir(), f"xray_viz-numba-{user}")


def private_dir(path: str) -> None:
    """Make ``path`` a directory of mode 0700, or check that the existing one is private.

    Raises
    ------
    PermissionError
        If ``path`` is not a directory (a symbolic link is not followed), is owned by another
        user, or is writable by its group or others: files in it could have been put there by
        someone else, and a cached kernel is machine code that gets run.
    """
    try:
        os.mkdir(path, 0o700)
    except FileExistsError:
        pass
    st = os.lstat(path)
    if not stat.S_ISDIR(st.st_mode):
        raise PermissionError(f"{path} is not a directory")
    if hasattr(os, "geteuid") and st.st_uid != os.geteuid():
        raise PermissionError(f"{path} is owned by uid {st.st_uid}, not by this user "
                              f"(uid {os.geteuid()})")
    if st.st_mode & 0o022:
        raise PermissionError(f"{path} is writable by other users "
                              f"(mode {stat.S_IMODE(st.st_mode):04o})")


class TempDirLocator(caching._SourceFileBackedLocatorMixin, caching._CacheLocator):
    """Place 4: the private per-user directory ``<tmp>/xray_viz-numba-<uid>``."""

    def __init__(self, py_func, py_file):
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._root = user_temp_root()
        self._cache_path = os.path.join(self._root, self.get_suitable_cache_subpath(py_file))

    def get_cache_path(self):
        return self._cache_path

    def ensure_cache_path(self):
        private_dir(self._root)
        super().ensure_cache_path()

    @classmethod
    def from_function(cls, py_func, py_file):
        if not os.path.exists(py_file):
            return None
        try:
            self = cls(py_func, py_file)
            self.ensure_cache_path()
        except OSError as exc:
            _refused["reason"] = _why(exc)
            return None
        return self


class _KernelCacheImpl(caching.CompileResultCacheImpl):
    # numba's places (1-3, and those of IPython and zip imports) in numba's order, then ours.
    _locator_classes = [*caching.CacheImpl._locator_classes, TempDirLocator]


class CheckedCacheFile(caching.IndexDataCacheFile):
    """numba's index and data files, with a checksum on the data and no error on a bad file.

    A bad index reads as empty (every kernel of it is compiled again and the index rewritten);
    a bad data file reads as missing (that kernel is compiled again and the file rewritten).
    """

    def _bad(self, path, why: str) -> None:
        _warn_once(("bad", path), f"kernel cache file {path} is unusable ({why}): compiling "
                   "that kernel again and rewriting the file")

    def _load_index(self):
        try:
            overloads = super()._load_index()
        except Exception as exc:  # truncated, garbled, unreadable: rebuilt, never fatal
            self._bad(self._index_path, _why(exc))
            return {}
        if not isinstance(overloads, dict):
            self._bad(self._index_path, f"holds a {type(overloads).__name__}, not an index")
            return {}
        return overloads

    def load(self, key):
        name = self._load_index().get(key)
        if name is None:
            return None
        try:
            return self._load_data(name)
        except FileNotFoundError:
            return None  # removed while the index still names it: numba's case too
        except Exception as exc:
            self._bad(self._data_path(name), _why(exc))
            return None

    def _load_data(self, name):
        path = self._data_path(name)
        with open(path, "rb") as f:
            blob = f.read()
        head = len(MAGIC) + _DIGEST
        if not blob.startswith(MAGIC):
            raise ValueError(f"not written by this cache ({len(blob)} bytes, no header)")
        if len(blob) < head or hashlib.sha256(blob[head:]).digest() != blob[len(MAGIC):head]:
            raise ValueError(f"truncated or corrupt ({len(blob)} bytes, checksum mismatch)")
        return pickle.loads(blob[head:])

    def _save_data(self, name, data):
        payload = self._dump(data)
        with self._open_for_write(self._data_path(name)) as f:
            f.write(MAGIC + hashlib.sha256(payload).digest() + payload)


class KernelCache(caching.FunctionCache):
    """numba's per-function cache, in the places above, checked, and never fatal."""

    _impl_class = _KernelCacheImpl

    def __init__(self, py_func):
        super().__init__(py_func)
        self._cache_file = CheckedCacheFile(cache_path=self._cache_path,
                                            filename_base=self._impl.filename_base,
                                            source_stamp=self._impl.locator.get_source_stamp())

    @property
    def locator(self):
        """The numba cache locator that chose :attr:`cache_path`."""
        return self._impl.locator

    def load_overload(self, sig, target_context):
        try:
            return super().load_overload(sig, target_context)
        except Exception as exc:  # e.g. a file numba can unpickle but not rebuild
            _warn_once(("load", self._cache_path, self._impl.filename_base),
                       f"kernel cache of {self._impl.filename_base} in {self._cache_path} "
                       f"could not be loaded ({_why(exc)}): compiling it again")
            return None

    def _index_key(self, sig, codegen):
        key = super()._index_key(sig, codegen)
        return (*key[:2], (*key[2], callee_digest(self._py_func)))

    def is_cached(self, sig, target_context) -> bool:
        """Whether the cache index holds ``sig`` for this machine and source (nothing loaded)."""
        try:
            key = self._index_key(sig, target_context.codegen())
            return key in self._cache_file._load_index()
        except Exception:  # unreadable: not cached (loading it would compile it again)
            return False

    def save_overload(self, sig, data):
        try:
            super().save_overload(sig, data)
        except Exception as exc:  # disk full, directory gone or made read-only meanwhile
            _warn_once(("save", self._cache_path),
                       f"cannot write the kernel cache in {self._cache_path} ({_why(exc)}): "
                       "compiled kernels will not be reused by the next process")


def _file_digest(path: str) -> str:
    st = os.stat(path)
    return _file_digest_of(path, st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=None)
def _file_digest_of(path: str, mtime_ns: int, size: int) -> str:
    # keyed by the file's time and size: a file changed while the process runs is read again
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


@functools.lru_cache(maxsize=None)
def callee_files(py_func) -> frozenset:
    """The source files of the xray_viz numba functions that ``py_func`` calls, directly or
    through others, by a global name (``helper(...)``) or a module's attribute
    (``module.helper(...)``): read from the names of its code and its globals."""
    own = py_func.__code__.co_filename
    files, seen, todo = set(), set(), [py_func]
    while todo:
        fn = todo.pop()
        names, codes = set(), [fn.__code__]
        while codes:                       # the function's own code and any nested in it
            code = codes.pop()
            names.update(code.co_names)
            codes += [c for c in code.co_consts if hasattr(c, "co_names")]
        scope = fn.__globals__
        found = [scope.get(n) for n in names]
        found += [getattr(m, n, None) for m in found if isinstance(m, types.ModuleType)
                  and m.__name__.startswith(PACKAGE) for n in names]
        for obj in found:
            py = getattr(obj, "py_func", None)
            if (isinstance(obj, dispatcher.Dispatcher) and id(py) not in seen
                    and str(getattr(py, "__module__", "")).startswith(PACKAGE)):
                seen.add(id(py))
                todo.append(py)
                if py.__code__.co_filename != own:
                    files.add(py.__code__.co_filename)
    return frozenset(files)


def callee_digest(py_func) -> str:
    """SHA-256 of the sources of ``callee_files`` (``""`` when there are none): part of
    the cache key of ``py_func``, so that a change in a numba function of another module that
    it calls compiles it again."""
    files = sorted(callee_files(py_func))
    if not files:
        return ""
    return hashlib.sha256("".join(f"{os.path.basename(f)}:{_file_digest(f)}\n"
                                  for f in files).encode()).hexdigest()


def _places(py_func, py_file, *, temp: bool = True) -> str:
    """The places 1-3 (and 4) for ``py_file``, for a warning."""
    places = []
    if config.CACHE_DIR:
        places.append(f"NUMBA_CACHE_DIR={config.CACHE_DIR}")
    places.append(os.path.join(os.path.dirname(py_file), "__pycache__"))
    with contextlib.suppress(Exception):
        places.append(caching.UserWideCacheLocator(py_func, py_file).get_cache_path())
    if temp:
        try:
            tmp = user_temp_root()
        except OSError:
            tmp = "no writable temporary directory"
        if "reason" in _refused:
            tmp = f"{tmp} (refused: {_refused['reason']})"
        places.append(tmp)
    return ", ".join(places)


def _say_where(cache: KernelCache, py_func, py_file) -> None:
    """One warning when the cache is not where numba alone would have put it."""
    locator = cache.locator
    if isinstance(locator, TempDirLocator):
        _warn_once("where", f"numba cannot write {_places(py_func, py_file, temp=False)}: "
                   f"the fast engine's compiled kernels are cached in {cache.cache_path} "
                   "(set NUMBA_CACHE_DIR to choose a directory)")
    elif (config.CACHE_DIR and not config.CACHE_LOCATOR_CLASSES
          and not isinstance(locator, caching.UserProvidedCacheLocator)):
        _warn_once("where", f"NUMBA_CACHE_DIR={config.CACHE_DIR} is not writable: the fast "
                   f"engine's compiled kernels are cached in {cache.cache_path}")


# numba's own (also when this module is imported again: the wrapper keeps it).
_numba_enable_caching = getattr(dispatcher.Dispatcher.enable_caching, "__wrapped__",
                                dispatcher.Dispatcher.enable_caching)


def _enable_caching(self):
    """``Dispatcher.enable_caching`` (run by ``@njit(cache=True)``), with :class:`KernelCache`
    for xray_viz's functions."""
    if not str(getattr(self.py_func, "__module__", "")).startswith(PACKAGE):
        return _numba_enable_caching(self)
    py_file = getattr(self.py_func.__code__, "co_filename", "?")
    try:
        cache = KernelCache(self.py_func)
    except Exception as exc:  # numba: "cannot cache function ...: no locator available"
        self._cache = caching.NullCache()
        why = "" if "no locator available" in str(exc) else f"; {_why(exc)}"
        _warn_once("where", f"no writable place to cache the fast engine's compiled kernels "
                   f"({_places(self.py_func, py_file)}{why}): every process compiles them "
                   "again (a few seconds each); set NUMBA_CACHE_DIR to a writable directory")
        return
    self._cache = cache
    _say_where(cache, self.py_func, py_file)


_enable_caching.__wrapped__ = _numba_enable_caching
dispatcher.Dispatcher.enable_caching = _enable_caching


def cache_path(kernel) -> str | None:
    """The directory where numba caches ``kernel`` (a numba dispatcher), or None if nowhere."""
    return getattr(kernel, "_cache", caching.NullCache()).cache_path


#: Cache path of kernels being compiled by background processes of this process (see
#: :func:`background_compile`), until a notice has said so.
_background: list = []


def background_compile(kernel) -> None:
    """Record that kernels are being compiled by other processes on behalf of this one (into
    the cache of ``kernel``): the active :func:`on_first_compile` callbacks are called when
    this process first needs one of them (:func:`needs_background`), not before, so that a
    command refusing its input says only that."""
    with _lock:
        _background[:] = [cache_path(kernel)]


def needs_background() -> None:
    """Called when this process first needs a kernel that one of its background processes
    compiles (waiting for it, or loading what it cached): the active :func:`on_first_compile`
    callbacks are called (once)."""
    with _lock:
        if not _background:
            return
        where, listeners = _background[0], list(_listeners)
    for listener in listeners:
        listener.fire(where)


_listeners: list = []


class _FirstCompile(event.Listener):
    def __init__(self, callback):
        self.callback = callback
        self.done = False

    def fire(self, where):
        if not self.done:
            self.done = True
            with _lock:
                _background.clear()
            self.callback(where)

    def on_start(self, ev):
        disp = (ev.data or {}).get("dispatcher")
        module = str(getattr(getattr(disp, "py_func", None), "__module__", ""))
        if not self.done and module.startswith(PACKAGE):
            self.fire(cache_path(disp))

    def on_end(self, ev):
        pass


@contextlib.contextmanager
def on_first_compile(callback):
    """Call ``callback(cache_path)`` when numba first compiles one of xray_viz's kernels.

    A kernel loaded from the cache is not compiled, so nothing is called on a warm cache.
    ``cache_path`` is where numba will cache the kernel (see :func:`cache_path`), None if the
    kernels are not cached. Kernels compiled for this process by background processes
    (:meth:`xray_viz.tracing._compile.KernelSet.prepare`) count: ``callback`` is called when this process
    first needs one of their kernels (:func:`needs_background`), inside the context.

    Parameters
    ----------
    callback : callable
        Called at most once, before the compilation starts (or the wait for a background
        process), in the thread that needs the kernel.
    """
    listener = _FirstCompile(callback)
    with _lock:
        _listeners.append(listener)
    try:
        with event.install_listener("numba:compile", listener):
            yield
    finally:
        with _lock:
            _listeners.remove(listener)
