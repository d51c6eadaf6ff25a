"""Every code block of the README and the docs runs as written.

The python, shell and TOML blocks of ``README.md`` and ``docs/**/*.md``/``*.rst`` (the docs'
``_readme/`` copies of README sections are the README's) are extracted; each python block runs
in a fresh namespace and each shell block command by command, in a temporary folder, with the
files they name provided by the blocks themselves (``xray-viz init``) or the bundled phantoms.
``xray-viz ...``, ``.venv/bin/xray-viz ...`` and ``python -m xray_viz ...`` run in this process
(:func:`xray_viz.cli.main`: the kernels are warm), ``python -c ...`` in a subprocess; anything
else in a shell block must be marked. A TOML block must parse (most are fragments that name
meshes of the reader's own).

A block that cannot run here (it installs, serves, opens a window or takes minutes) is marked
just above it, in Markdown with ``<!-- snippet: skip: WHY -->`` and in reST with
``.. snippet: skip: WHY``; the test reads the reason and refuses a mark without one.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from helpers import REPO

ROOT = REPO
SHELL = {"bash", "sh", "shell", "console"}
SKIP_MD = re.compile(r"^<!--\s*snippet:\s*skip:\s*(.*?)\s*-->\s*$")
SKIP_RST = re.compile(r"^\.\.\s+snippet:\s*skip:\s*(.*?)\s*$")


def _sources() -> list[Path]:
    docs = ROOT / "docs"
    found = [ROOT / "README.md"] + sorted(
        p for p in docs.rglob("*") if p.suffix in (".md", ".rst") and p.is_file()
        and "_readme" not in p.parts and "walkthroughs" not in p.parts
        and "examples" not in p.parts               # the galleries, written by a docs build
        and "generated" not in p.parts and "_build" not in p.parts)
    return found


def blocks(path: Path) -> list[dict]:
    """The code blocks of a Markdown or reST file: language, first line, text, skip reason."""
    lines = path.read_text(encoding="utf-8").splitlines()
    out = []

    def skip_above(i, pattern):
        j = i - 1
        while j >= 0 and not lines[j].strip():
            j -= 1
        m = pattern.match(lines[j].strip()) if j >= 0 else None
        return None if m is None else m.group(1)

    if path.suffix == ".md":
        i = 0
        while i < len(lines):
            m = re.match(r"^(\s*)(`{3,})\s*([\w+-]*)", lines[i])
            if m and not lines[i].strip().startswith("```{"):
                indent, fence, lang = m.groups()
                j = i + 1
                while j < len(lines) and not lines[j].strip().startswith(fence):
                    j += 1
                body = [line[len(indent):] for line in lines[i + 1:j]]
                out.append({"lang": lang.lower(), "line": i + 1, "text": "\n".join(body) + "\n",
                            "skip": skip_above(i, SKIP_MD)})
                i = j + 1
                continue
            if m:                                    # a MyST directive: skip to its end
                fence = m.group(2)
                i += 1
                while i < len(lines) and not lines[i].strip().startswith(fence):
                    i += 1
            i += 1
    else:
        for i, line in enumerate(lines):
            m = re.match(r"^(\s*)\.\. code-block::\s*(\w+)", line)
            if not m:
                continue
            base = len(m.group(1))
            j, body = i + 1, []
            while j < len(lines) and (not lines[j].strip() or
                                      len(lines[j]) - len(lines[j].lstrip()) > base):
                body.append(lines[j])
                j += 1
            text = "\n".join(body).strip("\n")
            pad = min(len(b) - len(b.lstrip()) for b in text.splitlines() if b.strip())
            text = "\n".join(b[pad:] for b in text.splitlines()) + "\n"
            out.append({"lang": m.group(2).lower(), "line": i + 1, "text": text,
                        "skip": skip_above(i, SKIP_RST)})
    return out


def _cases():
    cases = []
    for path in _sources():
        for b in blocks(path):
            if b["lang"] in SHELL | {"python", "toml"}:
                rel = path.relative_to(ROOT).as_posix()
                cases.append(pytest.param(path, b, id=f"{rel}:{b['line']}-{b['lang']}"))
    return cases


CASES = _cases()


def test_the_extraction_finds_the_blocks_it_must():
    ids = [c.id for c in CASES]
    assert any(i.startswith("README.md:") and i.endswith("-python") for i in ids)
    assert any(i.startswith("README.md:") and i.endswith("-bash") for i in ids)
    assert any(i.startswith("docs/index.rst:") and i.endswith("-python") for i in ids)
    assert len([i for i in ids if i.startswith("README.md:")]) >= 12
    md = blocks(ROOT / "README.md")
    assert all(b["skip"] is None or len(b["skip"]) > 20 for b in md)   # each skip says why


def commands(text: str) -> list[list[str]]:
    """A shell block's commands (continuation lines joined, comments dropped)."""
    joined = re.sub(r"\\\n", " ", text)
    return [argv for argv in (shlex.split(line, comments=True) for line in joined.splitlines())
            if argv]


def run_command(argv: list[str], where: str) -> None:
    if argv[0] in ("xray-viz", ".venv/bin/xray-viz"):
        args = argv[1:]
    elif argv[:3] == ["python", "-m", "xray_viz"]:
        args = argv[3:]
    elif argv[:2] == ["python", "-c"]:
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH",
                                                                                  ""))
        done = subprocess.run([sys.executable, *argv[1:]], env=env, capture_output=True,
                              text=True, timeout=120)
        assert done.returncode == 0, f"{where}: {shlex.join(argv)}\n{done.stderr}"
        return
    else:
        raise AssertionError(f"{where}: `{shlex.join(argv)}` cannot run in the snippet test: "
                             "mark the block <!-- snippet: skip: WHY --> or use xray-viz")
    from xray_viz.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(args)
        except SystemExit as exc:              # --help
            code = exc.code or 0
    assert code == 0, f"{where}: `{shlex.join(argv)}` exited {code}:\n{err.getvalue()}"


@pytest.mark.parametrize("path, block", CASES)
def test_code_block_runs(path, block, tmp_path, monkeypatch):
    where = f"{path.relative_to(ROOT)}:{block['line']}"
    if block["skip"] is not None:
        pytest.skip(f"{where}: {block['skip']}")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("PYVISTA_OFF_SCREEN", "true")
    if block["lang"] == "toml":
        tomllib.loads(block["text"])
    elif block["lang"] == "python":
        code = compile(block["text"], where, "exec")
        try:
            exec(code, {"__name__": "__snippet__"})
        finally:
            if "matplotlib.pyplot" in sys.modules:       # figures a block drew (plot())
                sys.modules["matplotlib.pyplot"].close("all")
    else:
        for argv in commands(block["text"]):
            run_command(argv, where)


#: A dotted name of the package in the text's inline code: `xray_viz.scan.read_zarr`,
#: `xray_viz.load_image(path)` (the call's arguments dropped); not a Sphinx role's target
#: (:func:`xray_viz.render.render` names the module, for Sphinx).
INLINE_NAME = re.compile(r"(?<![:`])`+(xray_viz(?:\.\w+)+)(?:\([^`]*\))?`")


def test_the_names_in_the_texts_inline_code_are_attributes():
    """Each `xray_viz.a.b` named in the inline code of the README and the docs' pages is what
    a reader typing it gets: reached by attribute access after ``import xray_viz`` (and its
    modules imported), as the issue's `xray_viz.scan.astra_vectors` was not (``xray_viz.scan``
    is the function)."""
    import importlib

    import xray_viz

    names = set()
    for path in _sources():
        names |= {m.group(1) for m in INLINE_NAME.finditer(path.read_text(encoding="utf-8"))}
    assert "xray_viz.load_image" in names                     # the search works
    bad = []
    for name in sorted(names):
        parts = name.split(".")
        for k in range(2, len(parts) + 1):                     # `import xray_viz.a.b` as far
            try:                                               # as it goes
                importlib.import_module(".".join(parts[:k]))
            except ImportError:
                break
        found = xray_viz
        try:
            for part in parts[1:]:
                found = getattr(found, part)
        except AttributeError:
            bad.append(name)
    assert bad == []


def test_the_readme_says_what_reconstruct_offers_for_a_helical_orbit():
    """The README's reconstruction paragraph names every ``--method`` of ``xray-viz
    reconstruct`` and those for a helical orbit (the iterative ones and MBIR), as the
    command's own help does; it said helical was not done while the help offered SART, CG and
    mbirjax for it."""
    from xray_viz.reconstruct import ITERATIVE, METHODS

    text = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    start = text.index("`xray-viz reconstruct")
    paragraph = text[start:text.index("##", start)]
    named = set(re.findall(r"--method (\w+)", paragraph)) | {
        m for m in ("fdk", "fbp") if m.upper() in paragraph}
    assert named == set(METHODS), named
    helical = [s for s in re.split(r"(?<=\.) ", paragraph) if "helical" in s]
    assert helical and not any("not done" in s or "not yet" in s for s in helical), helical
    offered = {m for s in helical for m in re.findall(r"--method (\w+)", s)}
    assert offered == set(ITERATIVE) | {"mbirjax"}, offered
