"""Tests of xray_viz.scan, xray_viz.orbit and xray_viz.poses: orbits, poses, scans and their stores."""
