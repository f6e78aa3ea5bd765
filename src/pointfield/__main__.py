import sys

from pointfield.cli import main

sys.exit(main())
