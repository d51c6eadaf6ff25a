"""Tests of the repository as a whole: lint, the import graph, installs, the Quick start, the disk cache rule."""
