"""Tests of xray_viz.cli and xray_viz.progress: the command line."""
