"""``python -m gonio.cli``."""

import sys

from gonio.cli import main

if __name__ == "__main__":
    sys.exit(main())
