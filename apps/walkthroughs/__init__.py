"""The walkthroughs: scripts that rebuild the thesis step by step.

See :mod:`xray_viz.walkthroughs`.

Installed as ``xray_viz._walkthroughs``; run one with ``xray-viz walkthrough N``.
"""
