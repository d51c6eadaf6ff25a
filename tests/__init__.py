"""The test suite of xray_viz: one folder per part of the package (ARCHITECTURE.md, "Tests").

Shared helpers live in tests/_support/ (on pytest's ``pythonpath``: ``from helpers import ...``).
"""
