"""``python -m carl_sumo``: the ``carl-sumo`` command line."""

import sys

from carl_sumo.cli import main

if __name__ == "__main__":
    sys.exit(main())
