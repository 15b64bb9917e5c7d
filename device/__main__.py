"""``python -m device``: the device's own command line."""

import sys

from device.cli import main

sys.exit(main())
