import sys

from sitl.process import main

sys.exit(main())
