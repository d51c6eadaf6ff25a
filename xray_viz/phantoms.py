"""The bundled phantom library: scene files and meshes shipped inside the package.

The files live in the repository's top-level ``phantoms/`` folder, made by
``phantoms/generate.py``, and are installed as the package ``xray_viz._phantoms``.

Examples
--------
>>> from xray_viz import phantoms
>>> "sphere" in phantoms.names()
True
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["names", "scene_path", "describe", "DEFAULT"]

#: The phantom rendered by ``xray-viz render default``.
DEFAULT = "frog"


def _root() -> Path:
    return Path(str(resources.files("xray_viz._phantoms")))


def names() -> list[str]:
    """Names of the bundled phantoms (``default`` is an alias of :data:`DEFAULT`)."""
    return sorted(p.stem for p in _root().glob("*.toml"))


def scene_path(name: str) -> Path | None:
    """Path of a bundled phantom's scene file, or None when there is no such phantom."""
    if name == "default":
        name = DEFAULT
    path = _root() / f"{name}.toml"
    return path if path.is_file() and "/" not in name and "\\" not in name else None


def describe(name: str) -> str:
    """The one-paragraph description at the top of a phantom's scene file (``# `` comments)."""
    path = scene_path(name)
    if path is None:
        raise KeyError(name)
    lines = []
    for line in path.read_text().splitlines():
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("#").strip())
    return " ".join(l for l in lines if l)
