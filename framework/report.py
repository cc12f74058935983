"""Reports of finished runs.

``write_run_report(run_dir)`` writes one run's ``report.md`` / ``report.html``;
``python -m framework.report DIR [DIR ...] [--out OUT]`` compares runs (methods x seeds)
in ``comparison.md`` / ``comparison.html``.
"""

from __future__ import annotations

import argparse
import sys

import matplotlib

matplotlib.use("Agg")

from framework.report_compare import write_comparison  # noqa: E402
from framework.report_data import ReportError  # noqa: E402
from framework.report_run import write_run_report  # noqa: E402

__all__ = ["ReportError", "main", "write_comparison", "write_run_report"]


def _parser() -> argparse.ArgumentParser:
    """The command-line parser."""
    parser = argparse.ArgumentParser(
        prog="python -m framework.report",
        description="Compare finished runs: per method and scene, errors over seeds, "
                    "speed against the symbolic method, links to each run's report.")
    parser.add_argument("dirs", nargs="+", metavar="DIR",
                        help="run folder (holds results.json) or sweep folder (searched recursively)")
    parser.add_argument("--out", default=None,
                        help="output folder (default: common parent of the DIRs)")
    return parser


def main(argv=None) -> int:
    """Command-line entry point; returns the exit code (2 on bad input, nothing written)."""
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    try:
        md_path, html_path = write_comparison(args.dirs, out=args.out)
    except ReportError as exc:
        print(f"report: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {md_path} and {html_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
