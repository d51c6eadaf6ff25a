"""The examples in the docstrings run and print what they say: pytest runs them, once
(``--doctest-modules`` over the package, pyproject.toml); these modules keep theirs."""

from __future__ import annotations

import importlib

import pytest

from helpers import doctest_examples

MODULES = [
    "xray_viz", "xray_viz.scene", "xray_viz.geometry", "xray_viz.tracing.intersect",
    "xray_viz.tracing.hits", "xray_viz.attenuation", "xray_viz.render", "xray_viz.output",
    "xray_viz.phantoms", "xray_viz.physics.imaging", "xray_viz.physics.detector",
    "xray_viz.physics.heel",
]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    assert doctest_examples(importlib.import_module(name)) > 0
