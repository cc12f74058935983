"""``python -m bench [--quick] [--sections a,b] [--jobs N] [--out BENCHMARKS.md]``: run the benchmark, rewrite
BENCHMARKS.md.

Sections: ``ratio`` (1, pass vs render), ``megapixel`` (1, a 1920x1080 view), ``memory`` (2), ``compare`` (3, methods at equal spp, the
learning-rate sweep), ``paper`` (4, Tables 1 and 2), ``materials`` (5), ``defaults`` (6,
accurate by default), ``field`` (7, field photographs), ``glossy`` (8, glossy kernels), ``geometry``
(9, geometry as a survey delivers it), ``survey`` (10, unknown sun and sky scales, vignetting and a
calibration panel on ``urban_canyon_survey``), ``misfit`` (11, what the model lacks: an unmasked car,
rotated poses, a facade off its mesh and textured walls on ``urban_canyon_misfit``; a red car in every
street view on ``urban_canyon_car``), ``holdout`` (12, every method's prediction of photographs it
never fitted against the floor: a street view of ``urban_canyon_field``, the morning of
``urban_canyon_survey``). ``--jobs N`` (default 2) runs the accuracy sections (:data:`bench.common.SHARED`) N at a
time, each in its own process, after the timed ones have run alone. ``--variant``
(default ``auto``: CUDA when usable, else LLVM) is the Mitsuba backend of every run; each stored
section records its variant, device and machine. Each
section's numbers are stored in ``bench/results/<section>.json`` (with the date, the commit and
the wall time of the run that measured them; a CUDA run's in ``bench/results/gpu/``, drawn in
BENCHMARKS.md's GPU part after the CPU's sections) and BENCHMARKS.md is rendered from every stored
section, so ``--sections field`` re-measures one section and keeps the others; each section of
BENCHMARKS.md states when it was measured. ``--quick`` stores under the run folder instead and
writes ``--out`` (default: the run folder's BENCHMARKS.md), never the committed results.
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import re
import sys
import time
from pathlib import Path

from bench import (accuracy, compare, field, geometry, glossy, holdout, materials, megapixel, memory, misfit,
                   paper, render_ratio, survey)
from bench.common import ROOT, SHARED
from framework.render import backend
from bench.machine import describe
from bench.markdown import README, readme_block, render, with_readme_block
from bench.sizes import DEFAULT, QUICK
from reports import write_comparison

SECTIONS = ("ratio", "megapixel", "memory", "compare", "paper", "materials", "defaults", "field", "glossy",
            "geometry", "survey", "misfit", "holdout")
RESULTS = ROOT / "bench" / "results"
#: sections that work in a folder of their own under the run folder, ``<run>/<section>/``, with
#: their pass caches in its ``cache/``, removed once the section's record is stored (a whole
#: benchmark's came to 13-20 GB, 2026-12-05, and filled the disk; nothing reads them after their
#: section: ``--resume`` reads finished runs' results). The comparison and the paper sections work
#: in the run folder itself and share its ``cache/`` (their observations): kept, as is an
#: interrupted section's.
OWN_FOLDER = tuple(n for n in SECTIONS if n not in ("compare", "paper"))

def parse(argv=None) -> argparse.Namespace:
    """Command-line arguments."""
    p = argparse.ArgumentParser(prog="python -m bench", description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="toy sizes, to check the code paths")
    p.add_argument("--sections", default=",".join(SECTIONS),
                   help=f"comma-separated sections to measure (default all: {','.join(SECTIONS)})")
    p.add_argument("--out", default=None, help="markdown file to (re)write (default BENCHMARKS.md; "
                                               "with --quick the run folder's)")
    p.add_argument("--runs", default=None, help="folder of the run folders (default bench/runs/<timestamp>)")
    p.add_argument("--resume", action="store_true",
                   help="the comparison and the materials sections reuse the runs of this --runs folder that "
                        "finished (an interrupted benchmark goes on where it stopped)")
    p.add_argument("--variant", default="auto",
                   help="Mitsuba variant of the sections that render: auto (CUDA when usable, else LLVM), cuda, llvm, "
                        "or a variant such as cuda_ad_rgb (mono scenes take the same backend's *_ad_mono)")
    p.add_argument("--render-only", action="store_true",
                   help="measure nothing: rewrite the markdown from the stored sections")
    p.add_argument("--store-only", action="store_true",
                   help="measure and store the sections, do not rewrite the markdown")
    p.add_argument("--jobs", type=int, default=2,
                   help=f"how many of the accuracy sections ({', '.join(SHARED)}) run at a time, each in its own "
                        "process, after the timed sections have run alone (default 2; 1: every section in turn)")
    args = p.parse_args(argv)
    if args.jobs < 1:
        p.error(f"--jobs {args.jobs} must be at least 1")
    if not (args.variant in ("auto", "cuda", "llvm")
            or re.fullmatch(r"(cuda|llvm)_ad_(rgb|mono)", args.variant)):
        p.error(f"--variant {args.variant} is not auto, cuda, llvm or a (cuda|llvm)_ad_(rgb|mono) variant")
    unknown = [x for x in args.sections.split(",") if x not in SECTIONS]
    if unknown:
        p.error(f"unknown section(s) {', '.join(unknown)}; choose from {', '.join(SECTIONS)}")
    return args


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


def measure(name: str, sizes, root: Path, resume: bool = False):
    """Run one section; its JSON-able data (``resume``: the comparison and materials sections
    reuse finished runs)."""
    if name == "ratio":
        return render_ratio.run(sizes, root / "ratio" / "cache", log)
    if name == "megapixel":
        return megapixel.run(sizes, root / "megapixel", log)
    if name == "memory":
        return memory.run(sizes, root / "memory", log)
    if name == "compare":
        rows = compare.run(sizes, root, log, resume=resume)
        path = compare.path_render(sizes, root, log)
        lr = compare.lr_sweep(sizes, root, log, resume=resume)
        return {"rows": rows, "lr": lr, "path": path, "report": _rel(comparison_report(rows, root / "comparison"))}
    if name == "paper":
        return paper.run(sizes, root, log)
    if name == "materials":
        return materials.run(sizes, root / "materials", log, resume=resume)
    if name == "defaults":
        return accuracy.run(sizes, root / "defaults", log)
    if name == "field":
        return field.run(sizes, root / "field", log)
    if name == "geometry":
        return geometry.run(sizes, root / "geometry", log)
    if name == "survey":
        return survey.run(sizes, root / "survey", log)
    if name == "misfit":
        return misfit.run(sizes, root / "misfit", log)
    if name == "holdout":
        return holdout.run(sizes, root / "holdout", log)
    return glossy.run(sizes, root / "glossy", log)


def main(argv=None) -> int:
    """Run the chosen sections, store them, render the markdown from every stored section."""
    args = parse(argv)
    sizes = on_backend(QUICK if args.quick else DEFAULT, args.variant)
    stamp = datetime.datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    root = Path(args.runs) if args.runs else ROOT / "bench" / "runs" / f"{stamp}{'_quick' if args.quick else ''}"
    root.mkdir(parents=True, exist_ok=True)
    on_gpu = sizes.variant.startswith("cuda")
    store = results_store(root, quick=args.quick, gpu=on_gpu)
    store.mkdir(parents=True, exist_ok=True)
    machine = describe(sizes.variant)
    log(f"bench ({sizes.name}) into {root}")
    names = [] if args.render_only else args.sections.split(",")
    shared = [n for n in SHARED if n in names] if args.jobs > 1 else []
    for name in (n for n in names if n not in shared):
        record = measured(name, sizes, root, machine, args.resume)
        (store / f"{name}.json").write_text(json.dumps(_relative(_light(record)), indent=1, default=str))
        drop_cache(root, name)
        log(f"[{name}] done in {record['wall_s'] / 60:.1f} min")
    if shared:
        in_processes(shared, args, root)
    if args.store_only:
        return 0
    stored = read_stored(results_store(root, quick=args.quick, gpu=False))
    gpu = read_stored(results_store(root, quick=args.quick, gpu=True))
    if on_gpu:          # the machine table is the CPU sections' machine, as they recorded it
        machine = next((rec["machine"] for rec in stored.values() if "machine" in rec), machine)
    command = "python -m bench" + (" --quick" if args.quick else "")
    out = Path(args.out) if args.out else (root / "BENCHMARKS.md" if args.quick else ROOT / "BENCHMARKS.md")
    out.write_text(render(machine, command, sizes, stored, gpu), encoding="utf-8")
    log(f"wrote {out}")
    block = readme_block(stored)
    if block is not None and not args.quick and args.out is None:
        readme = ROOT / README
        readme.write_text(with_readme_block(readme.read_text(encoding="utf-8"), block), encoding="utf-8")
        log(f"wrote {readme}'s results table")
    return 0


def results_store(root: Path, *, quick: bool, gpu: bool) -> Path:
    """Where a run stores its sections: ``bench/results`` (``--quick``: the run folder ``root``'s
    ``results``), and a CUDA run's in its ``gpu/``."""
    store = root / "results" if quick else RESULTS
    return store / "gpu" if gpu else store


def read_stored(store: Path) -> dict:
    """The sections stored in ``store`` (``bench/results``, or its ``gpu/`` for ``--variant cuda``), in
    :data:`SECTIONS` order."""
    return {n: json.loads((store / f"{n}.json").read_text()) for n in SECTIONS if (store / f"{n}.json").is_file()}


def drop_cache(root: Path, name: str) -> None:
    """Remove section ``name``'s pass caches under the run folder ``root`` (:data:`OWN_FOLDER`)."""
    import shutil
    if name in OWN_FOLDER:
        shutil.rmtree(root / name / "cache", ignore_errors=True)


def measured(name: str, sizes, root: Path, machine: dict, resume: bool) -> dict:
    """The stored record of one section, measured now: its data, the sizes, date, commit, device,
    and its start and end (epoch seconds: sections run side by side overlap)."""
    start, t0 = time.time(), time.perf_counter()
    data = measure(name, sizes, root, resume=resume)
    return {"section": name, "sizes": sizes.name, "sizes_values": dataclasses.asdict(sizes),
            "date": machine["date"], "git": machine["git"], "variant": machine["variant"],
            "device": machine["device"], "machine": machine, "wall_s": time.perf_counter() - t0, "start": start,
            "end": time.time(), "data": data}


def in_processes(names: list[str], args, root: Path) -> None:
    """Measure and store ``names``, ``args.jobs`` at a time, each by ``python -m bench --sections
    NAME --store-only`` into the same run folder; the first that fails stops the benchmark (after
    the others running beside it end), so no section is left from another commit unnoticed."""
    import subprocess
    common = ["--runs", str(root), "--variant", args.variant, "--jobs", "1", "--store-only",
              *(["--quick"] if args.quick else []), *(["--resume"] if args.resume else [])]
    waiting, running, failed = list(names), {}, []
    while waiting or running:
        while waiting and len(running) < args.jobs and not failed:
            name = waiting.pop(0)
            log(f"[{name}] started beside {', '.join(running) or 'nothing'}")
            running[name] = subprocess.Popen([sys.executable, "-m", "bench", "--sections", name, *common], cwd=ROOT)
        if failed:
            waiting.clear()
        for name, proc in list(running.items()):
            if proc.poll() is not None:
                del running[name]
                if proc.returncode:
                    failed.append(f"{name} (exit {proc.returncode})")
        time.sleep(1.0)
    if failed:
        raise SystemExit(f"bench: section(s) failed: {', '.join(failed)}; the stored results of the others are kept")


def on_backend(sizes, variant: str):
    """``sizes`` whose runs take ``variant``'s backend (``variant=cuda`` or ``llvm``: each scene then
    gets that backend's variant of its colour mode); ``auto`` leaves the runs' own default."""
    if variant == "auto":
        return dataclasses.replace(sizes, variant=backend.jit_backend("auto"))
    prefix = variant[:4]
    return dataclasses.replace(sizes, variant=prefix, extra=(*sizes.extra, f"variant={prefix}"))


#: results.json keys no section reads back (kept in the run folders)
HEAVY = ("cost_history", "cost_times_s", "correlation", "views", "relit", "initial_guess")


def _relative(obj):
    """``obj`` with every string path inside the repository written relative to it: the stored
    results are committed and name no machine's folders."""
    if isinstance(obj, dict):
        return {k: _relative(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_relative(v) for v in obj]
    if isinstance(obj, str) and obj.startswith(str(ROOT)):
        return obj[len(str(ROOT)):].lstrip("/") or "."
    return obj


def _light(record: dict) -> dict:
    """The record with the rows' results.json stripped of what no table reads (:data:`HEAVY`)."""
    def strip(row):
        if isinstance(row, dict) and isinstance(row.get("results"), dict):
            return {**row, "results": {k: v for k, v in row["results"].items() if k not in HEAVY}}
        return row
    data = record["data"]
    if isinstance(data, list):
        data = [strip(r) for r in data]
    elif isinstance(data, dict) and "lr" in data:          # the comparison
        data = {**data, "rows": [strip(r) for r in data["rows"]], "lr": [strip(r) for r in data["lr"]]}
    return {**record, "data": data}


def _rel(path) -> str:
    try:
        return str(Path(path).resolve().relative_to(ROOT))
    except (ValueError, TypeError):
        return str(path)


if __name__ == "__main__":
    sys.exit(main())
