"""Smoke test of the benchmark code paths (``python -m bench``) at toy size."""
from __future__ import annotations

import pytest

import dataclasses

from bench import markdown, render_ratio
from bench.child import tree_rss
from bench.common import compose, error_stats, observable_keys
from bench.memory import run_child
from bench.sizes import QUICK


def _fake_results(err: float, observable: bool = True) -> dict:
    """One observable and one unobservable parameter; the trace ends at the final estimate."""
    return {"channels": ["Y"],
            "parameters": [{"segment": "wall", "kernel": "diffuse", "estimate": [0.7], "reference": [0.72],
                            "error": [err], "observable": observable},
                           {"segment": "roof", "kernel": "diffuse", "estimate": None, "reference": [0.2],
                            "error": None, "observable": False}],
            "trace": [{"time_s": 0.5, "renders": 1, "estimate": [[0.5], [None]]},
                      {"time_s": 2.0, "renders": 1, "estimate": [[0.72 + err], [None]]}],
            "timings_s": {"total": 2.0, "render": 1.5, "compile": 0.25}, "renders": 1,
            "settings": {"variant": "llvm_ad_mono", "device": "cpu x"}}


def test_error_stats_skip_unobservable():
    res = _fake_results(-0.02)
    assert observable_keys(res) == {("wall", "diffuse")}
    assert error_stats(res) == (0.02, 0.02)


@pytest.mark.slow
def test_ratio_and_memory_on_tiny_scene(tiny_scene, tmp_path):
    """The pass-vs-render measurement and the memory wrapper run on a 16x16 scene."""
    cfg = compose([f"scene.dir={tiny_scene}", "views=all", "observe.spp=4", f"cache.dir={tmp_path / 'c'}",
                   "method.solver.starts=1"])
    problem, method = render_ratio.build_problem(cfg)
    row = render_ratio.measure_spp(problem, method, spp=2, reps=1)
    assert row["pass_s"] > 0 and row["render_s"] > 0 and row["n_params"] == 4
    out = run_child([f"scene.dir={tiny_scene}", "render.spp=2", "observe.spp=4", "report=false",
                     "method.solver.starts=1", f"cache.dir={tmp_path / 'c2'}", f"hydra.run.dir={tmp_path / 'r'}"])
    assert out["rc"] == 0 and out["maxrss_mib"] > 10 and (tmp_path / "r" / "results.json").is_file()


def _fake_ratio() -> dict:
    """Section 1's data as bench.render_ratio stores it, made up."""
    return {"rows": [{"spp": 4, "pass_s": 2.0, "render_s": 0.1, "ratio": 20.0, "solve_s": 0.01,
                      "solve_share": 0.1, "solve_share_pass": 0.005, "n_monomials": 455, "n_params": 12}],
            "view": "v", "size": "8x8", "max_bounces": 3, "reps": 1, "segments": 6,
            "kernels": ["diffuse", "specular"], "channels": ["Y"], "observe_spp": 8}


def test_markdown_renders_from_fake_numbers():
    import os
    sizes = dataclasses.replace(QUICK)
    assert tree_rss(__import__("psutil").Process(os.getpid())) > 0
    ratio = _fake_ratio()
    mem = [{"views": n, "image": s, "executor": ex, "rc": 0, "wall_s": 1.0, "maxrss_mib": 100.0 + n + s,
            "tree_peak_mib": 100.0, "timings_s": {"render": 1.0, "solve": 0.1}}
           for s in (32, 64) for n, ex in ((4, "serial"), (1, "serial"), (4, "dask"))]
    rows = [{"label": lab, "scene": "urban_canyon", "views": v, "n_views": 1, "budget": 20, "run_dir": "x",
             "results": _fake_results(0.01)} for v in ("single", "all")
            for lab in ("symbolic", "iterative (noise fresh)", "differentiable")]
    mono = [{"label": lab, "scene": "urban_canyon_mono", "views": v, "n_views": 1, "budget": 20,
             "run_dir": "x", "results": _fake_results(0.01)}
            for lab, v in (("lambertian_prior", "single"), ("symbolic", "single"), ("symbolic", "all"))]
    path = {"path_s": 0.5, "reps": 3, "spp": 4, "view": "v", "max_depth": 4}
    machine = {"cpu": "c", "cores": 2, "ram_gib": 1.0, "variant": "v", "mitsuba": "m", "drjit": "d",
               "python": "p", "platform": "x", "date": "today", "git": "g"}
    stamp = {"date": "today", "git": "g", "sizes": "quick", "wall_s": 60.0}
    defaults = [{"label": "symbolic, all views", "target": "all_within", "met": True, "detail": "worst 0.004",
                 "renders": 3, "stopped": "converged", "wall_s": 10.0, "maxrss_mib": 500.0}]
    field = [{"label": "default (+ robust Cauchy)", "worst_diffuse": 0.01, "worst_specular": 0.02, "median": 0.003,
              "gain_error": 0.01, "ill_determined": 1, "image_rmse": 0.01, "renders": 2, "wall_s": 5.0,
              "met": True}]
    stored = {name: {**stamp, "data": data} for name, data in (
        ("ratio", ratio), ("memory", mem), ("compare", {"rows": rows, "lr": [], "report": "r.md", "path": path}), ("paper", mono),
        ("defaults", defaults), ("field", field))}
    text = markdown.render(machine, "python -m bench --quick", sizes, stored)
    assert "## 6. Accurate by default" in text and "## 7. Field photographs" in text
    assert "_Measured today at commit g (quick sizes, 1.0 min)._" in text
    assert "| all 6 sections | | g | 6.0 |" in text     # one commit: the six sections' 1.0 min summed
    assert "python -m bench --quick" in text and "Table 2" in text and "**not met**" in text
    # every method ends at the same error 0.01 at t = 2 s: the baselines reach the symbolic's there
    assert "| differentiable | 0.010 | 2.0 s (1 renders), 1.0 x symbolic | 0.010 (too few iterates to tell) |" in text
    assert "| 4 | 64x64 | dask |" in text
    # 42: the device, and a baseline's render (1.5 s, compile 0.25 s apart) against path's 0.5 s
    assert "Rendered with llvm_ad_mono on cpu x: every time and ratio below is measured there." in text
    assert "| iterative (noise fresh) | 1 | 1.5 | 0.25 | 1.5000 | 3.00 | **not met** |" in text
    assert "32x32: +2 % (133 MiB at 1 view to 136 MiB at 4); 64x64: +2 % (165 MiB at 1 view to 168 MiB at 4)" in text


def test_kernel_split_tells_kernels_from_host():
    """kernel_split: a Dr.Jit kernel's execution is counted, a host-only sleep is not."""
    import time

    import drjit as dr
    import mitsuba as mi
    from framework.render.jit_timing import kernel_split
    wall, kernels, out = kernel_split(lambda: dr.eval(dr.sin(dr.arange(mi.Float, 4_000_000) * dr.opaque(mi.Float, 0.5))))
    assert kernels > 0 and wall >= kernels
    wall, kernels, _ = kernel_split(lambda: time.sleep(0.2))
    assert kernels == 0 and wall >= 0.2


def test_bench_variant_option():
    """--variant: a backend name or an rgb/mono JIT variant; the runs get the backend (mono scenes
    then take its *_ad_mono variant); anything else is refused by the parser."""
    from bench.__main__ import on_backend, parse
    assert parse(["--variant", "cuda_ad_rgb"]).variant == "cuda_ad_rgb"
    with pytest.raises(SystemExit):
        parse(["--variant", "cuda_ad_spectral"])
    sizes = on_backend(QUICK, "llvm_ad_rgb")
    assert sizes.variant == "llvm" and sizes.extra[-1] == "variant=llvm"
    assert on_backend(QUICK, "auto").extra == QUICK.extra


def test_total_wall_of_sections_run_side_by_side():
    """The "all sections" row is the run's wall time, first start to last end: sections of 1 min
    (0-60 s) and two of 2 min side by side (60-180 s, 70-190 s) took 3.2 min, not the 5 min their
    walls sum to, and the text says they shared the machine; without start and end, the sum."""
    from bench.markdown import section_machine
    machine = {"cpu": "c", "cores": 2, "ram_gib": 1.0, "variant": "v", "mitsuba": "m", "drjit": "d",
               "python": "p", "platform": "x"}
    spans = {"ratio": (0.0, 60.0), "survey": (60.0, 180.0), "misfit": (70.0, 190.0)}
    stored = {n: {"date": "today", "git": "g", "wall_s": e - s, "start": s, "end": e} for n, (s, e) in spans.items()}
    text = "\n".join(section_machine(machine, "python -m bench", QUICK, stored))
    assert "| all 3 sections | | g | 3.2 |" in text and "two at a time" in text
    alone = {n: {k: v for k, v in r.items() if k not in ("start", "end")} for n, r in stored.items()}
    text = "\n".join(section_machine(machine, "python -m bench", QUICK, alone))
    assert "| all 3 sections | | g | 5.0 |" in text and "two at a time" not in text


def test_bench_jobs_errors():
    from bench.__main__ import parse
    assert parse([]).jobs == 2 and parse(["--jobs", "1"]).jobs == 1
    with pytest.raises(SystemExit):
        parse(["--jobs", "0"])


def test_sections_in_processes_run_n_at_a_time(monkeypatch, tmp_path):
    """in_processes: at most --jobs children at once, each ``python -m bench --sections NAME
    --store-only --jobs 1`` into the same run folder; a failed child stops the start of the others
    and the benchmark exits non-zero naming it."""
    import subprocess
    import bench.__main__ as main
    started, alive = [], []

    class Child:
        def __init__(self, cmd, cwd):
            self.name = cmd[cmd.index("--sections") + 1]
            self.cmd, self.polls, self.returncode = cmd, 0, None
            started.append(self)
            alive.append(self)
            assert len(alive) <= 2                       # never more than --jobs at once

        def poll(self):
            self.polls += 1
            if self.polls >= 2:
                self.returncode = 3 if self.name == "field" else 0
                alive.remove(self) if self in alive else None
            return self.returncode

    monkeypatch.setattr(subprocess, "Popen", Child)
    monkeypatch.setattr(main.time, "sleep", lambda s: None)
    args = main.parse(["--jobs", "2", "--quick"])
    main.in_processes(["survey", "misfit", "holdout"], args, tmp_path)
    assert [c.name for c in started] == ["survey", "misfit", "holdout"]
    assert all(c.cmd[c.cmd.index("--runs") + 1] == str(tmp_path) and "--store-only" in c.cmd and "--quick" in c.cmd
               and c.cmd[c.cmd.index("--jobs") + 1] == "1" for c in started)
    started.clear()
    with pytest.raises(SystemExit, match="field"):
        main.in_processes(["field", "defaults", "holdout", "glossy"], args, tmp_path)
    assert "glossy" not in [c.name for c in started]    # nothing starts after the failure is seen


def test_a_stored_section_leaves_no_pass_cache(tmp_path, monkeypatch):
    """Once a section's record is stored its pass caches go (a whole benchmark's filled 13-20 GB),
    its runs stay; the comparison's and the paper's shared cache stays. Every section but those two
    is given ``<run>/<section>/`` to work in (the ratio section its ``cache/``), so a new section
    cannot leave a cache behind unnoticed."""
    import bench.__main__ as main
    assert set(main.OWN_FOLDER) == set(main.SECTIONS) - {"compare", "paper"}
    modules = {"ratio": main.render_ratio, "defaults": main.accuracy}
    for name in main.OWN_FOLDER:
        module = modules.get(name) or getattr(main, name)
        monkeypatch.setattr(module, "run", lambda sizes, work, log, **kw: work)
        given = main.measure(name, QUICK, tmp_path)
        assert given == tmp_path / name / ("cache" if name == "ratio" else ""), name
    for rel in ("survey/cache/x/tile_0.npz", "survey/runs/b/results.json", "cache/observed/o.npz",
                "ratio/cache/call0/t.npz"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("x")
    main.drop_cache(tmp_path, "survey")
    main.drop_cache(tmp_path, "ratio")
    main.drop_cache(tmp_path, "compare")
    main.drop_cache(tmp_path, "glossy")              # no cache of its own: nothing to remove
    assert not (tmp_path / "survey" / "cache").exists() and not (tmp_path / "ratio" / "cache").exists()
    assert (tmp_path / "survey" / "runs" / "b" / "results.json").is_file()
    assert (tmp_path / "cache" / "observed" / "o.npz").is_file()


def test_gpu_sections_render_after_the_cpus(tmp_path):
    """A section measured with ``--variant cuda`` (stored under ``bench/results/gpu/``) is drawn in
    the GPU part, after the CPU's sections, its heading one level down and its stamp naming the
    device; the CPU's own section 1 stays where it was."""
    import json

    from bench.__main__ import read_stored
    machine = {"cpu": "c", "cores": 2, "ram_gib": 1.0, "variant": "llvm_ad_rgb", "mitsuba": "m", "drjit": "d",
               "python": "p", "platform": "x", "date": "today", "git": "g"}
    cpu = {"date": "today", "git": "g", "sizes": "quick", "wall_s": 60.0, "variant": "llvm_ad_rgb (rgb scenes)",
           "device": "CPU", "data": _fake_ratio()}
    gpu = {**cpu, "variant": "cuda_ad_rgb (rgb scenes)", "device": "NVIDIA H200", "git": "h",
           "machine": {**machine, "cpu": "Xeon", "cores": 16}}
    (tmp_path / "gpu").mkdir()
    (tmp_path / "ratio.json").write_text(json.dumps(cpu))
    (tmp_path / "gpu" / "ratio.json").write_text(json.dumps(gpu))
    stored, on_gpu = read_stored(tmp_path), read_stored(tmp_path / "gpu")
    assert list(stored) == list(on_gpu) == ["ratio"]
    text = markdown.render(machine, "python -m bench", QUICK, stored, on_gpu)
    cpu_at, gpu_at = text.index("## 1. Symbolic pass vs plain render"), text.index("## On a GPU")
    assert cpu_at < gpu_at < text.index("### 1. Symbolic pass vs plain render")
    assert "_Measured today at commit h on NVIDIA H200 (quick sizes, 1.0 min)._" in text
    assert "_Measured today at commit g (quick sizes, 1.0 min)._" in text
    assert "| NVIDIA H200 | Xeon | 16 | cuda_ad_rgb (rgb scenes) |" in text
    assert "pass / render | <= 1.3 |" in text[:gpu_at] and "pass / render | <= 1.5 |" in text[gpu_at:]


def test_warm_kernels_runs_every_method_once_and_keeps_nothing(tmp_path, monkeypatch):
    """The comparison's warm-up: every method at WARM_BUDGET renders, in order; its run folder and
    pass cache removed; a warm-up that raises is logged and the others still run."""
    from bench import compare
    calls, logged = [], []

    def fake_run_one(sizes, root, label, scene, n_views, overrides, budget, log=print, resume=False):
        calls.append((label, budget))
        for folder in compare._folders(root, label, scene, "single"):
            folder.mkdir(parents=True)
        if "differentiable" in label:
            raise RuntimeError("no AD here")

    monkeypatch.setattr(compare, "run_one", fake_run_one)
    compare.warm_kernels(QUICK, tmp_path, "urban_canyon", 1, log=logged.append)
    assert calls == [(f"warm-up {label}", compare.WARM_BUDGET) for label, _, _ in compare.METHODS]
    assert not list((tmp_path / "urban_canyon" / "single").iterdir())
    assert not list((tmp_path / "cache" / "urban_canyon" / "single").iterdir())
    assert len(logged) == 1 and "warm-up of differentiable failed" in logged[0]
