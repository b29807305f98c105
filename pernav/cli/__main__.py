"""``python -m pernav.cli``: the ``pernav`` command line."""

import sys

from pernav.cli import main

sys.exit(main())
