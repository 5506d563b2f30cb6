"""``python -m agents.evaluate``: :func:`agents.evaluate.cli.main`."""

import sys

from agents.evaluate.cli import main

if __name__ == "__main__":  # importing the module (pkgutil.walk_packages does) runs nothing
    sys.exit(main())
