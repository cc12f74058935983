"""bench.gpu_checks: its steps within the time budget, and the summary of the runs they leave."""
from __future__ import annotations

import json
import sys

import yaml

from bench import gpu_checks


def test_steps_stop_at_the_budget(tmp_path, monkeypatch):
    """A step that outlasts what is left is stopped (``timeout``), a step with less than
    ``MIN_STEP_S`` left is not started (exit None), a finished one reports its exit code."""
    py = sys.executable
    monkeypatch.setattr(gpu_checks, "MIN_STEP_S", 1.0)
    monkeypatch.setattr(gpu_checks, "steps", lambda out, backend, quick: [
        ("ok", [py, "-c", "print('hi')"], 30.0), ("slow", [py, "-c", "import time; time.sleep(30)"], 30.0),
        ("late", [py, "-c", "pass"], 30.0)])
    done = gpu_checks.run_steps(tmp_path, "llvm", True, budget_s=3.0)
    assert [(d["step"], d["rc"]) for d in done] == [("ok", 0), ("slow", "timeout"), ("late", None)]
    assert (tmp_path / "ok.log").read_text().strip() == "hi"


def test_summary_tables_every_run(tmp_path):
    """Each results.json under a step's folder is a row: variant, device, times, the sweep's
    distinguishing overrides; a missing stage reads n/a."""
    for run, where, unc in (("0", "host", 0.8), ("1", "device", None)):
        folder = tmp_path / "all_views" / "symbolic" / "urban_canyon" / run
        (folder / ".hydra").mkdir(parents=True)
        stages = {} if unc is None else {"uncertainty": unc}
        (folder / "results.json").write_text(json.dumps({
            "timings_s": {"method": 4.2, "render": 2.5, "solve": 1.1, "compile": 1.3},
            "settings": {"variant": "cuda_ad_rgb", "device": "NVIDIA H200"}, "solve_stages_s": stages}))
        (folder / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(
            ["method=symbolic", "seed=0", f"method.std_device={where}"]))
    text = gpu_checks.summary(tmp_path, [{"step": "all_views", "rc": 0, "wall_s": 12.0},
                                         {"step": "survey", "rc": None, "wall_s": 0.0}])
    assert "| all_views | 0 | 12 |" in text and "| survey | None | 0 |" in text
    assert "| symbolic/urban_canyon/0 | cuda_ad_rgb | NVIDIA H200 | 4.20 | 2.50 | 1.10 | 0.80 | 1.30 | seed=0 method.std_device=host |" in text
    assert "| symbolic/urban_canyon/1 | cuda_ad_rgb | NVIDIA H200 | 4.20 | 2.50 | 1.10 | n/a | 1.30 | seed=0 method.std_device=device |" in text


def test_steps_name_the_backend_everywhere(tmp_path):
    """Every step's runs take the asked backend; the bench step stores only (the markdown is
    rendered where the results are committed)."""
    for name, command, limit in gpu_checks.steps(tmp_path, "cuda", False):
        assert limit > 0
        assert ("--variant" in command and "cuda" in command) if name == "bench" else "variant=cuda" in command
    assert "--store-only" in gpu_checks.steps(tmp_path, "cuda", False)[0][1]
