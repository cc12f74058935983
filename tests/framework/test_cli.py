"""The command line of docs/cli.md and results.json of docs/results.md: every registered method on a tiny scene, bad input, sweeps."""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from factory import make_tiny_scene

from framework.config import compose
from framework.experiment import run_experiment
from framework.registry import available_methods

FAST = ["render.spp=8", "observe.spp=32", "budget.renders=12", "report=false",
        "method.solver.starts=1"]
METHOD_FAST = {"iterative": ["method.max_eval=2", "method.noise=fixed"],
               "differentiable": ["method.iterations=2"]}


def _fast(method):
    extra = METHOD_FAST.get(method, [])
    if method in ("symbolic", "lambertian_prior"):
        return FAST + extra
    return [o for o in FAST if not o.startswith("method.solver")] + extra


@pytest.mark.parametrize("method", available_methods())
def test_every_method_runs_on_a_tiny_scene(method, tiny_scene, tmp_path):
    """Each registered method writes a results.json of the documented shape within its render budget."""
    cfg = compose([f"method={method}", f"scene.dir={tiny_scene}", f"cache.dir={tmp_path / 'cache'}",
                    *_fast(method)])
    results = run_experiment(cfg, tmp_path / "run")
    on_disk = json.loads((tmp_path / "run" / "results.json").read_text())
    assert on_disk["method"] == method and on_disk["scene"] == "tiny"
    assert on_disk["channels"] == ["R", "G", "B"]
    assert 1 <= on_disk["renders"] <= 12
    for p in on_disk["parameters"]:
        assert set(p) >= {"segment", "kernel", "estimate", "reference", "error"}
        assert len(p["estimate"]) == 3
        assert p["error"] == pytest.approx([e - r for e, r in zip(p["estimate"], p["reference"])], abs=1e-12)
    assert {"render", "solve", "total"} <= set(on_disk["timings_s"])
    assert results["image_rmse"] is not None
    if method in ("symbolic", "lambertian_prior"):      # their solve split into stages
        stages = on_disk["solve_stages_s"]
        assert {"psd", "solver", "uncertainty", "other"} <= set(stages) and min(stages.values()) >= 0
        assert sum(stages.values()) == pytest.approx(on_disk["timings_s"]["solve"], rel=1e-9)


def test_solve_stages_of_a_field_run(tiny_scene, tmp_path):
    """Photographs (8-bit: robust rounds, the bias correction) and one refinement pass with
    registration: solve_stages_s holds each part of the solve the run report breaks the time into
    (was: psd, solver and uncertainty only, a few % of the solve)."""
    from factory import write_png8
    rng = np.random.default_rng(0)
    for name in ("view_0.png", "view_1.png"):
        write_png8(tiny_scene / "images" / name, rng.integers(60, 180, (16, 16, 3)))
    cfg = compose([f"scene.dir={tiny_scene}", "cache.dir=null", "render.spp=4", "method.refine=1",
                   "method.align=shift", "method.irls.iterations=2", "method.irls.tol=0", "report=false"])
    run_experiment(cfg, tmp_path / "run")
    on_disk = json.loads((tmp_path / "run" / "results.json").read_text())
    stages = on_disk["solve_stages_s"]
    assert {"weighted_systems", "robust_weights", "registration", "bias_refits", "other"} <= set(stages), stages
    assert sum(stages.values()) == pytest.approx(on_disk["timings_s"]["solve"], rel=1e-9)


def _cli(args, cwd):
    env = dict(os.environ, HYDRA_FULL_ERROR="0")
    return subprocess.run([sys.executable, "-m", "framework.run", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


def _tree_digest(root: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        if p.is_file():
            h.update(str(p.relative_to(root)).encode() + p.read_bytes())
    return h.hexdigest()


@pytest.mark.slow
def test_cli_bad_scene_errors(tiny_scene, tmp_path):
    """One line naming the file, exit 2, no results.json, the user's folder untouched."""
    (tiny_scene / "meshes/block.ply").unlink()
    before = _tree_digest(tiny_scene)
    run_dir = tmp_path / "run"
    proc = _cli([f"scene.dir={tiny_scene}", f"hydra.run.dir={run_dir}", f"cache.dir={tmp_path / 'c'}"], tmp_path)
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert lines == [f"error: {tiny_scene / 'meshes/block.ply'}: mesh file missing; fix the path in scene.yaml"]
    assert not (run_dir / "results.json").exists()
    assert _tree_digest(tiny_scene) == before


@pytest.mark.slow
def test_cli_bad_setting_errors(tiny_scene, tmp_path):
    proc = _cli([f"scene.dir={tiny_scene}", "render.max_bounces=0", f"hydra.run.dir={tmp_path / 'r'}"], tmp_path)
    assert proc.returncode == 2
    assert proc.stderr.strip() == "error: render.max_bounces=0 is out of range: use an integer [1, 8]"
    proc = _cli([f"scene.dir={tiny_scene}", "variant=llvm_ad_foo", f"hydra.run.dir={tmp_path / 'r'}"], tmp_path)
    assert proc.returncode == 2 and "variant=llvm_ad_foo is not a Mitsuba variant" in proc.stderr


@pytest.mark.slow
def test_cli_run_writes_run_folder(tiny_scene, tmp_path):
    """`python -m framework.run` end to end: results.json, report.md and report.html."""
    proc = _cli(["method=symbolic", f"scene.dir={tiny_scene}", f"cache.dir={tmp_path / 'c'}",
                 "render.spp=8", "observe.spp=32", "method.solver.starts=1"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    runs = list((tmp_path / "outputs" / "symbolic" / "tiny").iterdir())
    assert len(runs) == 1
    for name in ("results.json", "report.md", "report.html"):
        assert (runs[0] / name).is_file(), name


@pytest.mark.slow
def test_rgb_then_mono_scene_in_one_process(tmp_path):
    """Plugins are per Mitsuba variant: an rgb and a mono symbolic run share one process."""
    for ch in ("rgb", "mono", "rgb"):
        scene = make_tiny_scene(tmp_path / ch, channels=ch)
        cfg = compose(["method=symbolic", f"scene.dir={scene}", f"cache.dir={tmp_path / 'c'}", *FAST])
        results = run_experiment(cfg, tmp_path / f"run_{ch}")
        assert results["settings"]["variant"] == f"llvm_ad_{ch}"
        assert len(results["parameters"][0]["estimate"]) == (3 if ch == "rgb" else 1)
