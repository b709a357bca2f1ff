"""``python -m groundstation`` is the ground-station process (``quadsitl gcs``)."""

import sys

from groundstation.gcs import main

sys.exit(main())
