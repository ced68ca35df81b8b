"""``python -m teleop``: the ``teleop`` command."""

import sys

from teleop.cli import main

if __name__ == "__main__":
    sys.exit(main())
