"""``python -m xray_viz``: the ``xray-viz`` command line (:mod:`xray_viz.cli`)."""

from xray_viz.cli import run

if __name__ == "__main__":
    run()
