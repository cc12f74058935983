"""Reports of finished runs: the run report, the comparison of runs, their plots, image panels
and tables.

``write_run_report(run_dir)`` writes one run's ``report.md`` / ``report.html``;
``python -m reports DIR [DIR ...] [--out OUT]`` compares runs (methods x seeds)
in ``comparison.md`` / ``comparison.html``.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

from reports.compare import write_comparison  # noqa: E402
from reports.data import ReportError  # noqa: E402
from reports.run import write_run_report  # noqa: E402

__all__ = ["ReportError", "write_comparison", "write_run_report"]
