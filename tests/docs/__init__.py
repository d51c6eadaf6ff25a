"""Tests of the documentation: docstring examples, README and docs snippets, the site, xray_viz.walkthroughs."""
