"""Tests of xray_viz.viz: the viewer (desktop, web, notebook) and its images."""
