import sys

from pointfield.cli import main

if __name__ == "__main__":  # not when imported (the API reference imports every module)
    sys.exit(main())
