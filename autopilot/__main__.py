import sys

from autopilot.process import main

sys.exit(main())
