"""``python -m groundstation`` is the ground-station process (``quadsitl gcs``)."""

import sys

from groundstation.gcs import main
from quadsitl.process_util import run_stoppable

sys.exit(run_stoppable(main, stopped=None, name="quadsitl gcs"))  # a flight stopped before it began is not a success
