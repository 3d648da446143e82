"""``python -m tendonsense``: the command line (:mod:`tendonsense.cli`)."""

import sys

from .cli import main

if __name__ == "__main__":
    sys.exit(main())
