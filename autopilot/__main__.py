import sys

from autopilot.cli import main

sys.exit(main())
