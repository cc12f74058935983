"""``python -m reports DIR [DIR ...] [--out OUT]``: compare finished runs (methods x seeds) in
``comparison.md`` / ``comparison.html`` (``python -m framework.report`` is the same command)."""
from __future__ import annotations

import argparse
import sys

from reports import ReportError, write_comparison


def _parser(prog: str) -> argparse.ArgumentParser:
    """The command-line parser."""
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Compare finished runs: per method and scene, errors over seeds, "
                    "speed against the symbolic method, links to each run's report.")
    parser.add_argument("dirs", nargs="+", metavar="DIR",
                        help="run folder (holds results.json) or sweep folder (searched recursively)")
    parser.add_argument("--out", default=None,
                        help="output folder (default: common parent of the DIRs)")
    return parser


def main(argv=None, *, prog: str = "python -m reports") -> int:
    """Command-line entry point; returns the exit code (2 on bad input, nothing written)."""
    try:
        args = _parser(prog).parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    try:
        md_path, html_path = write_comparison(args.dirs, out=args.out)
    except ReportError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:                   # e.g. an --out folder that cannot be written
        print(f"error: cannot write the report in {exc.filename or args.out} ({exc.strerror}): "
              "choose a writable folder with --out", file=sys.stderr)
        return 2
    print(f"wrote {md_path} and {html_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
