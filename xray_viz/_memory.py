"""How much memory this process may still take: the one reading of the limits that every
up-front memory check uses (:func:`xray_viz.render.check_memory`, a scan's stack, a label
map's or CT's voxels).

The least of: the machine's available memory (``MemAvailable`` of ``/proc/meminfo``), the
process's own limits (``RLIMIT_AS``, ``ulimit -v`` / ``prlimit --as``, less the address space
already mapped; ``RLIMIT_DATA`` less the data already allocated) and its control group's
(cgroup v2 ``memory.max`` less ``memory.current``, v1 ``memory.limit_in_bytes`` less
``memory.usage_in_bytes``, each usage without its reclaimable page cache, ``inactive_file``
of ``memory.stat``; at its own level and every level above it: a container's limit).
Nothing of xray_viz is imported here.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["available_memory", "memory_limit", "format_bytes", "describe", "check_allocation"]

#: A cgroup v1 "no limit" is a huge number (the page-rounded ``LLONG_MAX``).
_UNLIMITED = 1 << 60


def _meminfo(root: Path) -> int | None:
    try:
        with open(root / "proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _status(root: Path, key: str) -> int | None:
    """A ``kB`` figure of ``/proc/self/status`` in bytes (``VmSize``, ``VmData``)."""
    try:
        with open(root / "proc/self/status") as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _rlimits(root: Path) -> list[tuple[int, str]]:
    try:
        import resource
    except ImportError:                            # not on Unix
        return []
    out = []
    for name, used_key, what in (("RLIMIT_AS", "VmSize", "address-space limit (ulimit -v)"),
                                 ("RLIMIT_DATA", "VmData", "data-size limit (ulimit -d)")):
        which = getattr(resource, name, None)
        if which is None:
            continue
        soft = resource.getrlimit(which)[0]
        if soft == resource.RLIM_INFINITY or soft < 0:
            continue
        used = _status(root, used_key) or 0
        out.append((max(0, soft - used), f"this process's {what} of {format_bytes(soft)}"))
    return out


def _read_int(path: Path) -> int | None:
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    if text == "max":
        return None
    try:
        value = int(text)
    except ValueError:
        return None
    return None if value >= _UNLIMITED else value


def _inactive_file(level: Path, key: str) -> int:
    """Reclaimable page cache of a cgroup (``memory.stat``'s ``key``): counted in its usage,
    but given back under pressure (as ``docker stats`` leaves it out)."""
    try:
        for line in (level / "memory.stat").read_text().splitlines():
            name, _, value = line.partition(" ")
            if name == key:
                return int(value)
    except (OSError, ValueError):
        pass
    return 0


def _levels(mount: Path, rel: str):
    """The cgroup folders of the process under ``mount``: its own and every parent up to the
    mount (a container sees its own group as the mount itself)."""
    seen = set()
    p = mount / rel.strip("/") if rel.strip("/") else mount
    while True:
        if p not in seen and p.is_dir():
            seen.add(p)
            yield p
        if p == mount or mount not in p.parents:
            break
        p = p.parent
    if mount not in seen and mount.is_dir():
        yield mount


def _cgroups(root: Path) -> list[tuple[int, str]]:
    try:
        lines = (root / "proc/self/cgroup").read_text().splitlines()
    except OSError:
        return []
    out = []
    for line in lines:
        parts = line.split(":", 2)
        if len(parts) != 3:
            continue
        _, controllers, rel = parts
        if controllers == "":                       # v2: "0::/path"
            mount = root / "sys/fs/cgroup"
            for level in _levels(mount, rel):
                limit = _read_int(level / "memory.max")
                if limit is not None:
                    used = (_read_int(level / "memory.current") or 0) - _inactive_file(
                        level, "inactive_file")
                    out.append((max(0, limit - used),
                                f"the control group's memory.max of {format_bytes(limit)}"))
        elif "memory" in controllers.split(","):    # v1: "4:memory:/path"
            mount = root / "sys/fs/cgroup/memory"
            for level in _levels(mount, rel):
                limit = _read_int(level / "memory.limit_in_bytes")
                if limit is not None:
                    used = (_read_int(level / "memory.usage_in_bytes") or 0) - _inactive_file(
                        level, "total_inactive_file")
                    out.append((max(0, limit - used), "the control group's "
                                f"memory.limit_in_bytes of {format_bytes(limit)}"))
    return out


def memory_limit(*, root="/") -> tuple[int, str] | None:
    """``(bytes this process may still take, what limits it)``, or None where nothing is
    known (not Linux, no limit).

    ``root``: where ``/proc`` and ``/sys`` are (tests).

    Examples
    --------
    >>> got = memory_limit()
    >>> got is None or (got[0] >= 0 and isinstance(got[1], str))
    True
    """
    root = Path(root)
    found = []
    avail = _meminfo(root)
    if avail is not None:
        found.append((avail, f"this machine has {format_bytes(avail)} available"))
    found += _rlimits(root) + _cgroups(root)
    return min(found, key=lambda f: f[0]) if found else None


def available_memory(*, root="/") -> int | None:
    """Bytes this process may still take (:func:`memory_limit`), or None where unknown.

    Examples
    --------
    >>> n = available_memory()
    >>> n is None or n >= 0
    True
    """
    got = memory_limit(root=root)
    return None if got is None else got[0]


def format_bytes(nbytes: float) -> str:
    """``"3.0 GiB"``, ``"18 GiB"``, ``"512 MiB"``.

    Examples
    --------
    >>> format_bytes(3 << 30), format_bytes(20000 * 20000 * 48), format_bytes(1 << 20)
    ('3.0 GiB', '18 GiB', '1.0 MiB')
    """
    for unit, size in (("TiB", 1 << 40), ("GiB", 1 << 30), ("MiB", 1 << 20)):
        if nbytes >= size or unit == "MiB":
            v = nbytes / size
            return f"{v:.0f} {unit}" if v >= 10 else f"{v:.1f} {unit}"
    raise AssertionError  # pragma: no cover


def describe(available: int) -> str:
    """What limits this process to ``available`` bytes, in words (the binding limit of
    :func:`memory_limit` when it is that figure, else the machine's)."""
    got = memory_limit()
    if got is not None and got[0] == available and not got[1].startswith("this machine"):
        return f"this process may take {format_bytes(available)} more: {got[1]}"
    return f"this machine has {format_bytes(available)} available"


def check_allocation(nbytes: int, what: str, fix: str, *, error=MemoryError,
                     available=None) -> None:
    """Refuse, in one line, an allocation of ``nbytes`` for ``what`` that cannot fit
    (:func:`available_memory`; no check where that is unknown): raise ``error`` saying how
    much is needed, what limits it and ``fix``.

    Examples
    --------
    >>> check_allocation(1024, "a small array", "nothing to do")
    >>> try:
    ...     check_allocation(1 << 62, "the stack", "write it to a store", error=ValueError)
    ... except ValueError as exc:
    ...     print(str(exc).split(" (")[0])
    the stack needs about 4194304 TiB
    """
    free = available_memory() if available is None else available
    if free is None or nbytes <= free:
        return
    raise error(f"{what} needs about {format_bytes(nbytes)} ({describe(free)}): {fix}")

