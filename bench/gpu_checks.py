"""``python -m bench.gpu_checks OUT [--backend cuda] [--budget-s 540] [--quick]``: the GPU checks of
the symbolic method in one call, for a machine lent for minutes.

Each step runs in its own process with a timeout cut to what is left of ``--budget-s``, in the
order of what matters most, so a slow step costs the ones after it and never the whole call:

1. ``bench``: sections 1 and 1b (pass / render at 16, 64 and 256 spp and at 1920x1080 / 64 spp,
   the pass's host share) with ``python -m bench --variant BACKEND --store-only``; a CUDA run stores
   them in ``bench/results/gpu/`` (BENCHMARKS.md draws them beside the CPU's), copied to ``OUT``;
2. ``single``: ``method=symbolic scene=urban_canyon`` at seeds 0 and 1 in one process (Hydra's
   ``-m``): the second run's method time is after warm-up (results.json ``timings_s.method``,
   compile apart in ``timings_s.compile``);
3. ``all_views``: the same on every view, with ``method.std_device`` host and device: the std's
   products on the host and on the device, side by side (``solve_stages_s.uncertainty``);
4. ``survey``: ``scene=urban_canyon_survey views=all`` (the sun and sky, the lens, the panel).

``OUT`` receives ``summary.md`` (a table per step: every run's variant, device, method, passes,
solve, std and compile times), each step's log, and the runs' results.json files, all in
``checks.tar.gz`` too, and ``bench-results/`` (the stored sections): put those in
``bench/results/gpu/`` of the project's checkout and run ``python -m bench --render-only`` there to
draw them in BENCHMARKS.md beside the CPU's, under the CPU machine's table. With ``--quick`` (the bench's toy sizes, small views: to try the script on
a CPU with ``--backend llvm``) the numbers mean nothing.
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tarfile
import time
from pathlib import Path

from bench.common import ROOT

#: a step is not started with less time left than this (it could not finish)
MIN_STEP_S = 20.0


def steps(out: Path, backend: str, quick: bool) -> list[tuple[str, list[str], float]]:
    """``(name, command, timeout in s)`` of each check, in order."""
    run = [sys.executable, "-m", "framework.run", "-m", "method=symbolic", f"variant={backend}", "report=false",
           *(["render.spp=4", "observe.spp=8", "method.refine=0"] if quick else [])]
    bench = [sys.executable, "-m", "bench", "--variant", backend, "--sections", "ratio,megapixel", "--store-only",
             "--runs", str(out / "bench-runs"), *(["--quick"] if quick else [])]
    return [
        ("bench", bench, 240.0),
        ("single", [*run, "scene=urban_canyon", "seed=0,1", f"cache.dir={out / 'cache'}",
                    f"hydra.sweep.dir={out / 'single'}"], 60.0),
        ("all_views", [*run, "scene=urban_canyon", "views=all", "seed=0,1", "method.std_device=host,device",
                       f"cache.dir={out / 'cache'}", f"hydra.sweep.dir={out / 'all_views'}"], 150.0),
        ("survey", [*run, "scene=urban_canyon_survey", "views=all", "seed=0", f"cache.dir={out / 'cache'}",
                    f"hydra.sweep.dir={out / 'survey'}"], 200.0),
    ]


def run_steps(out: Path, backend: str, quick: bool, budget_s: float) -> list[dict]:
    """Run :func:`steps` within ``budget_s``; each step's name, exit code (None: not started, under
    :data:`MIN_STEP_S` left; ``timeout``: stopped at what was left) and wall time."""
    t0, done = time.monotonic(), []
    for name, command, limit in steps(out, backend, quick):
        left = budget_s - (time.monotonic() - t0)
        if left < MIN_STEP_S:
            done.append({"step": name, "rc": None, "wall_s": 0.0})
            continue
        start = time.monotonic()
        with open(out / f"{name}.log", "w") as log:
            try:
                rc = subprocess.run(command, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
                                    timeout=min(limit, left)).returncode
            except subprocess.TimeoutExpired:
                rc = "timeout"
        done.append({"step": name, "rc": rc, "wall_s": time.monotonic() - start})
        print(f"gpu_checks: {name} exit {rc} in {done[-1]['wall_s']:.0f} s", flush=True)
    return done


def run_rows(folder: Path) -> list[list]:
    """A row per results.json under ``folder``: run, variant, device, method, passes, solve, std and
    compile seconds, and the overrides that tell the runs apart."""
    rows = []
    for path in sorted(folder.rglob("results.json")):     # Hydra's sweep: <method>/<scene>/<overrides>/
        r = json.loads(path.read_text())
        t, s = r.get("timings_s", {}), r.get("settings", {})
        stages = r.get("solve_stages_s") or {}
        rows.append([str(path.parent.relative_to(folder)), s.get("variant", "?"), s.get("device", "?"),
                     *(_s(t.get(k)) for k in ("method", "render", "solve")), _s(stages.get("uncertainty")),
                     _s(t.get("compile")), " ".join(_overrides(path.parent))])
    return rows


def _s(value) -> str:
    return "n/a" if value is None else f"{value:.2f}"


def _overrides(run_dir: Path) -> list[str]:
    """The sweep's overrides of a run (Hydra's ``.hydra/overrides.yaml``), those that differ between runs."""
    path = run_dir / ".hydra" / "overrides.yaml"
    if not path.is_file():
        return []
    import yaml
    return [o for o in yaml.safe_load(path.read_text()) or [] if o.startswith(("seed=", "method.std_device="))]


def summary(out: Path, done: list[dict]) -> str:
    """``summary.md``: the steps' exit codes and times, and each step's runs (:func:`run_rows`)."""
    from bench.tables import table
    lines = ["# GPU checks", ""] + table(["step", "exit", "wall (s)"],
                                         [[d["step"], d["rc"], f"{d['wall_s']:.0f}"] for d in done]) + [""]
    header = ["run", "variant", "device", "method (s)", "passes (s)", "solve (s)", "std (s)", "compile (s)",
              "overrides"]
    for d in done:
        rows = run_rows(out / d["step"])
        if rows:
            lines += [f"## {d['step']}", ""] + table(header, rows) + [""]
    return "\n".join(lines) + "\n"


def keep(out: Path, backend: str, quick: bool) -> None:
    """Copy the stored bench sections into ``OUT/bench-results`` and pack logs, summary, stored
    sections and results.json files into ``OUT/checks.tar.gz``."""
    from bench.__main__ import results_store     # the bench's own rule; its sections' imports only here
    store = results_store(out / "bench-runs", quick=quick, gpu=backend.startswith("cuda"))
    if store.is_dir():
        shutil.copytree(store, out / "bench-results", dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns("gpu"))
    with tarfile.open(out / "checks.tar.gz", "w:gz") as tar:
        for path in sorted(out.rglob("*")):
            if path.is_file() and (path.suffix in (".log", ".md") or path.name == "results.json"
                                   or path.parent.name == "bench-results"):
                tar.add(path, arcname=str(path.relative_to(out)))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.gpu_checks", description=__doc__.splitlines()[0])
    p.add_argument("out", help="folder for the summary, logs and runs (created)")
    p.add_argument("--backend", default="cuda", choices=("cuda", "llvm"), help="Dr.Jit backend of every run")
    p.add_argument("--budget-s", type=float, default=540.0, help="seconds for all the steps together")
    p.add_argument("--quick", action="store_true", help="toy sizes: to try the script, not to measure")
    args = p.parse_args(argv)
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    done = run_steps(out, args.backend, args.quick, args.budget_s)
    (out / "summary.md").write_text(summary(out, done), encoding="utf-8")
    keep(out, args.backend, args.quick)
    print((out / "summary.md").read_text(), flush=True)
    return 0 if all(d["rc"] == 0 for d in done) else 1


if __name__ == "__main__":
    raise SystemExit(main())
