"""``python -m lbc_core``: the ``lbc`` command line."""

import sys

from .cli import main

sys.exit(main())
