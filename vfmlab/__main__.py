import sys

from vfmlab.cli import main

sys.exit(main())
