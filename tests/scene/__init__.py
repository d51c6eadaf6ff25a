"""Tests of xray_viz.scene, scene_file, scene_options and _checks: scenes, their files and the checks of their values."""
