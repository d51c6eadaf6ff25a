"""Which fast-engine kernels a scene file most likely needs first (for the command line's
background compilation, :meth:`xray_viz.tracing._compile.KernelSet.prepare`)."""

from __future__ import annotations

from pathlib import Path


def likely_paths(scene: str) -> list | None:
    """Kernel paths (keys of :data:`xray_viz.tracing._raster.PATHS`) that the scene file or
    bundled phantom ``scene`` most likely needs: several ``[[body]]`` tables, the banded
    several-bodies path; one, the one-body path. None when the file cannot be read (then
    every kernel is as urgent as any other). A guess only: a wrong one costs time, never a
    result (a kernel not ready is waited for, or compiled, when first used).

    Examples
    --------
    >>> likely_paths("default"), likely_paths("sphere"), likely_paths("no/such.toml")
    (['setup', 'banded', 'multi'], ['setup', 'direct'], None)
    """
    import tomllib

    from xray_viz import phantoms

    path = Path(scene)
    if not path.is_file():
        path = phantoms.scene_path(scene)
    try:
        n = len(tomllib.loads(path.read_text(encoding="utf-8")).get("body", []))
    except (OSError, AttributeError, TypeError, ValueError, RecursionError):
        return None
    return ["setup", "banded", "multi"] if n > 1 else ["setup", "direct"]
