"""Tests of xray_viz.output: image files and their formats."""
