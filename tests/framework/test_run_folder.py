"""The run folder: what may be claimed, what a failed run removes (only what it wrote), and image
names that cannot write outside ``images/``."""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from framework.config import compose
from framework.errors import ConfigError
from framework.experiment import run_experiment
from framework.registry import MethodResult
from framework.results import RunFolder, image_paths, write_view_images


def test_claim_refuses_foreign_content(tmp_path, tiny_scene):
    (tmp_path / "other_scene").mkdir()
    (tmp_path / "other_scene" / "scene.yaml").write_text("")
    with pytest.raises(ConfigError, match=r"holds a scene \(scene.yaml\), which runs never write to"):
        RunFolder.claim(tmp_path / "other_scene", scene_root=tiny_scene)
    with pytest.raises(ConfigError, match=r"is inside the scene folder"):
        RunFolder.claim(tiny_scene / "outputs" / "run", scene_root=tiny_scene)
    (tmp_path / "f").write_text("")
    with pytest.raises(ConfigError, match=r"run folder .*/f \(hydra.run.dir\) is a file"):
        RunFolder.claim(tmp_path / "f", scene_root=tiny_scene)


def test_discard_removes_only_what_the_run_wrote(tmp_path, tiny_scene):
    """A sweep job's folder (claimed after Hydra wrote .hydra/ and the log) is removed with what
    the run wrote; a file that appeared meanwhile survives, and so does its folder."""
    job = tmp_path / "job"
    (job / ".hydra").mkdir(parents=True)
    (job / "run.log").write_text("")
    folder = RunFolder.claim(job, scene_root=tiny_scene, hydra_written=(".hydra", "run.log"))
    (job / "images").mkdir()
    (job / "report.md").write_text("")
    (job / "notes.txt").write_text("someone else's")
    folder.discard()
    assert [p.name for p in job.iterdir()] == ["notes.txt"]
    (job / "notes.txt").unlink()
    folder.discard()
    assert not job.exists()


def test_discard_keeps_a_finished_run(tmp_path, tiny_scene):
    folder = RunFolder.claim(tmp_path / "run", scene_root=tiny_scene)
    (tmp_path / "run" / "images").mkdir(parents=True)
    (tmp_path / "run" / "results.json").write_text("{}")
    folder.discard()
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["images", "results.json"]


def test_image_paths_stay_below_images():
    paths = image_paths(["../../../../tmp/x/evil.png", "left/top_000.png", "/abs/a.png", "__/x.png",
                         "../x.png", "a.png", "A.png"])
    assert paths == {"../../../../tmp/x/evil.png": "images/__/__/__/__/tmp/x/evil.png",
                     "left/top_000.png": "images/left/top_000.png", "/abs/a.png": "images/abs/a.png",
                     "__/x.png": "images/__/x.png", "../x.png": "images/__/x.png~2",
                     "a.png": "images/a.png", "A.png": "images/A.png~2"}


def test_view_images_never_leave_the_run_folder(tmp_path):
    """Whatever the names, every file lands under run/images/ and results.json keeps the names."""
    names = ["../../escaped.png", "left/top_000.png"]
    image = np.full((4, 4, 3), 0.5, np.float32)
    problem = SimpleNamespace(cameras=[SimpleNamespace(name=n) for n in names],
                              observed={n: image for n in names}, scene=SimpleNamespace(channels=("R", "G", "B")))
    result = MethodResult(estimate=np.zeros((1, 3)), renders=1, reconstructions={n: image for n in names})
    run = tmp_path / "a" / "run"
    entries = write_view_images(run, problem, result, {n: np.zeros((4, 4), int) for n in names})
    assert [e["name"] for e in entries] == names
    written = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*") if p.is_file())
    assert written == sorted(f"a/run/{e[k]}" for e in entries for k in ("observed", "reconstruction", "segments"))
    assert all(w.startswith("a/run/images/") for w in written)


@pytest.mark.slow
def test_view_name_with_subfolder_runs(tiny_scene, tmp_path):
    """A COLMAP image name with a sub-folder (left/view_1.png) gets its outputs below images/left/."""
    images_txt = tiny_scene / "sparse" / "images.txt"
    images_txt.write_text(images_txt.read_text().replace("view_1.png", "left/view_1.png"))
    cfg = compose([f"scene.dir={tiny_scene}", "cache.dir=null", "render.spp=4", "observe.spp=8",
                   "method.solver.starts=1", "views=all"])
    run_experiment(cfg, tmp_path / "run")
    views = {v["name"]: v for v in json.loads((tmp_path / "run" / "results.json").read_text())["views"]}
    assert sorted(views) == ["left/view_1.png", "view_0.png"]
    assert views["left/view_1.png"]["observed"] == "images/left/view_1.png.observed.exr"
    assert (tmp_path / "run" / "images" / "left" / "view_1.png.observed.exr").is_file()
