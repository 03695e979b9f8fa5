import sys

from tap_bench.cli import main

sys.exit(main())
