"""``python -m xray_viz``: the ``xray-viz`` command line (:mod:`xray_viz.cli`)."""

import sys

from xray_viz.cli import main

if __name__ == "__main__":
    sys.exit(main())
