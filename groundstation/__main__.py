"""``python -m groundstation`` is the ``quadsitl`` command."""

import sys

from groundstation.cli import main

sys.exit(main())
