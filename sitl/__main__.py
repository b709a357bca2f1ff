import sys

from quadsitl.process_util import run_stoppable
from sitl.process import main

sys.exit(run_stoppable(main, name="quadsitl plant"))
