import sys

from autopilot.process import main
from quadsitl.process_util import run_stoppable

sys.exit(run_stoppable(main, name="quadsitl autopilot"))
