"""``python -m madp.robot``: the ``madp-robot`` command line (:mod:`madp.robot.cli`)."""

import sys

from madp.robot.cli import main

if __name__ == "__main__":
    sys.exit(main())
