"""``python -m bench [--quick] [--out BENCHMARKS.md]``: run the benchmark, rewrite BENCHMARKS.md."""
from __future__ import annotations

import argparse
import datetime
import json
import sys
import time
from pathlib import Path

from bench import compare, materials, memory, paper, render_ratio
from bench.common import ROOT
from bench.machine import describe
from bench.markdown import render
from bench.sizes import DEFAULT, QUICK
from reports import write_comparison


def parse(argv=None) -> argparse.Namespace:
    """Command-line arguments."""
    p = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    p.add_argument("--quick", action="store_true", help="toy sizes, to check the code paths")
    p.add_argument("--out", default=str(ROOT / "BENCHMARKS.md"), help="markdown file to (re)write")
    p.add_argument("--runs", default=None, help="folder of the run folders (default bench/runs/<timestamp>)")
    return p.parse_args(argv)


def log(msg: str) -> None:
    """Progress line on stderr with a timestamp."""
    print(f"{time.strftime('%H:%M:%S')} {msg}", file=sys.stderr, flush=True)


def comparison_report(rows: list[dict], out: Path):
    """reports's comparison of the run folders; its markdown path (or the error text)."""
    try:
        md, _ = write_comparison([r["run_dir"] for r in rows], out=out)
        return md
    except Exception as exc:  # the benchmark numbers stand without the report
        log(f"comparison report failed: {exc!r}")
        return f"(not written: {exc!r})"


def main(argv=None) -> int:
    """Run the four sections and write the markdown; returns the exit code."""
    args = parse(argv)
    sizes = QUICK if args.quick else DEFAULT
    stamp = datetime.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    root = Path(args.runs) if args.runs else ROOT / "bench" / "runs" / f"{stamp}{'_quick' if args.quick else ''}"
    root.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    machine = describe()
    log(f"bench ({sizes.name}) into {root}")
    ratio = render_ratio.run(sizes, root / "cache" / "ratio", log)
    mem = memory.run(sizes, root / "memory", log)
    cmp_rows = compare.run(sizes, root, log)
    lr_rows = compare.lr_sweep(sizes, root, log)
    mat_rows = materials.run(sizes, root / "materials", log)
    mono = paper.run(sizes, root, log)
    report_md = comparison_report(cmp_rows + mono, root / "comparison")
    command = "python -m bench" + (" --quick" if args.quick else "")
    wall = time.perf_counter() - t0
    text = render(machine, command, wall, sizes, ratio, mem, cmp_rows, mono, _rel(report_md), lr_rows, mat_rows)
    Path(args.out).write_text(text, encoding="utf-8")
    _dump(root, ratio, mem, cmp_rows + mono + lr_rows, mat_rows)
    log(f"wrote {args.out} in {wall / 60:.1f} min")
    return 0


def _rel(path) -> str:
    try:
        return str(Path(path).resolve().relative_to(ROOT))
    except (ValueError, TypeError):
        return str(path)


def _dump(root: Path, ratio: dict, mem: list, rows: list, mat_rows: list) -> None:
    """The raw numbers as bench.json next to the runs."""
    light = [{k: v for k, v in r.items() if k != "results"} | {"timings_s": r["results"]["timings_s"],
             "renders": r["results"]["renders"]} for r in rows]
    (root / "bench.json").write_text(json.dumps({"ratio": ratio, "memory": mem, "runs": light,
                                                 "materials": mat_rows}, indent=2))


if __name__ == "__main__":
    sys.exit(main())
