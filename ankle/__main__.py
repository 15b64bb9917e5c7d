"""``python -m ankle``: the same as the ``ankle`` command."""

import sys

from ankle.cli import main

sys.exit(main())
