"""``python -m diffkin``: the command line of :mod:`diffkin.cli`."""

import sys

from diffkin.cli import main

if __name__ == "__main__":
    sys.exit(main())
