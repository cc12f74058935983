"""``python -m framework.report DIR [DIR ...]``: the command-line name of :mod:`reports`'s
comparison, kept for the documented command line (``docs/cli.md``)."""
import sys

from reports.__main__ import main

if __name__ == "__main__":
    sys.exit(main(prog="python -m framework.report"))
