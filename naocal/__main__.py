import sys

from naocal.tools.cli import main

sys.exit(main())
