"""``python -m gonio.cli``."""

import sys

from gonio.cli import main

sys.exit(main())
