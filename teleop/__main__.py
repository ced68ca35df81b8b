"""``python -m teleop``: the ``teleop`` command."""

import sys

from teleop.app.cli import main

if __name__ == "__main__":
    sys.exit(main())
