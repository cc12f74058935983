"""Issue 42: the comparison says which device its times were measured on (results.json
``settings.variant`` and ``settings.device``), and never pools a method's runs on two devices."""
from __future__ import annotations

import json
from pathlib import Path

from fakes import make_fake_run

from reports.compare import write_comparison

H200 = {"variant": "cuda_ad_rgb", "device": "NVIDIA H200"}
CPU = {"variant": "llvm_ad_rgb", "device": "AMD EPYC, 2 cores"}


def _on(run: Path, place: dict) -> Path:
    data = json.loads((run / "results.json").read_text())
    data["settings"].update(place)
    (run / "results.json").write_text(json.dumps(data))
    return run


def test_comparison_states_the_device(tmp_path):
    """Every run on one GPU: the comparison names it beside its times (was: no device at all)."""
    for method in ("symbolic", "iterative"):
        _on(make_fake_run(tmp_path / "sweep" / method, method=method), H200)
    text = write_comparison([tmp_path / "sweep"])[0].read_text()
    assert ("Every run rendered with cuda_ad_rgb on NVIDIA H200: the times and ratios below are measured "
            "there.") in text


def test_comparison_keeps_devices_apart(tmp_path):
    """A method's runs on a CPU (two seeds) and a GPU (one) are two variants, the GPU one labelled,
    not three seeds of one (was: pooled, their times averaged)."""
    for seed, place in enumerate((CPU, CPU, H200)):
        _on(make_fake_run(tmp_path / "sweep" / f"i{seed}", method="iterative", seed=seed), place)
    text = write_comparison([tmp_path / "sweep"])[0].read_text()
    assert "The runs rendered on 2 devices (cuda_ad_rgb on NVIDIA H200; llvm_ad_rgb on AMD EPYC, 2 cores)" in text
    assert "| iterative | 2 | 0, 1 |" in text
    assert "| iterative (device=NVIDIA H200, variant=cuda_ad_rgb) | 1 | 2 |" in text
