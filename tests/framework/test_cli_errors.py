"""Bad command-line input: one line ``error: ...`` saying what is wrong and the fix, exit status 2,
no results.json, the scene folder and anything already in the run folder untouched.

Most cases run the command line's own check, :func:`framework.run.preflight`, in this process
(it fails before Hydra starts, so that is what the command prints); a few run
``python -m framework.run`` to see the whole path: the printed line, the status, the folders.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from factory import cli, error_line, make_tiny_scene, snapshot

import framework.run
from framework.config import compose
from framework.errors import ConfigError
from framework.experiment import prepare

TINY = ["render.spp=4", "observe.spp=8", "report=false"]

SETTING_ERRORS = [
    ("views=[]", "views=[] selects no view: name at least one image, or use views=all"),
    ("views=[view_0.png,view_0.png]", "views lists view_0.png more than once: name each view once"),
    ("observe.max_depth=0", "observe.max_depth=0 renders nothing (Mitsuba max_depth): use -1 (unbounded) "
                            "or an integer >= 2"),
    ("observe.max_depth=1", "observe.max_depth=1 renders only the emitters (Mitsuba max_depth): use -1 "
                            "(unbounded) or an integer >= 2"),
    ("seed=1.5", "seed=1.5 is not an integer: use an integer >= 0"),
    ("seed=-1", "seed=-1 is out of range: use an integer >= 0"),
    ("seed=abc", "seed=abc is not an integer: use an integer >= 0"),
    ("scene.dir=", "scene.dir is empty: give a scene folder (scene.dir=path/to/scene), or scene.dir=null "
                   "for the bundled scene"),
    ("variant=scalar_rgb", "variant=scalar_rgb is a scalar variant, and the methods need a JIT one: use "
                           "variant=auto, an llvm_ad_* or (NVIDIA GPU) a cuda_ad_* variant"),
    ("render.spp=4294967296", "render.spp=4294967296 is out of range: use an integer [1, 4294967295] "
                              "(Mitsuba's sample_count is a 32-bit unsigned integer)"),
    ("observe.noise=abc", "observe.noise=abc is not a number: use a number >= 0"),
    ("method.kernels=[nonsense]", "method.kernels has unknown kernel(s) nonsense: use all, or a list of the "
                                  "registered kernels (diffuse, specular)"),
    ("method=nonsense", "method=nonsense is not a method; choose one of: differentiable, iterative, "
                        "lambertian_prior, symbolic, symbolic_paper"),
    ("executor=nonsense", "executor=nonsense is not an executor; choose one of: dask, serial"),
    ("scene=nonsense", "scene=nonsense is not a bundled scene; choose one of: "),
    ("foo=1", "Could not override 'foo'. To append to your config use +foo=1 (docs/cli.md lists the keys)"),
    ("scene.dir=/tmp/ü", "scene.dir=/tmp/ü: Hydra reads non-ASCII characters only inside quotes; write the "
                         "argument as 'scene.dir=\"/tmp/ü\"'"),
    # non-finite option values: accepted before, the run then failed at the results.json write
    ("method.align_max_px=inf", "method.align_max_px=inf is not finite (inf or nan): give finite numbers"),
    ("method.refine_tol=inf", "method.refine_tol=inf is not finite (inf or nan): give finite numbers"),
    ("method.irls.tol=inf", "method.irls.tol=inf is not finite (inf or nan): give finite numbers"),
    ("method.relight.sun_irradiance=[1,inf,1]", "method.relight.sun_irradiance=(1, inf, 1) is not finite"),
    # an option of other methods: Hydra's hint (+method.align=...) only led to another refusal
    ("method.align=rotation", "method.align is not an option of method iterative: the methods that have it: "
                              "lambertian_prior, symbolic, symbolic_paper (choose one with method=<name>); "
                              "iterative's options: "),
    ("+method.align=rotation", "method.align is not an option of method iterative: the methods that have it: "
                               "lambertian_prior, symbolic, symbolic_paper"),
    ("method.solver.starts=2", "method.solver.starts is not an option of method iterative: the methods that "
                               "have it: lambertian_prior, symbolic, symbolic_paper"),
    ("+method.nonsense=1", "method.nonsense is not an option of method iterative: no method has it; "
                           "iterative's options: "),
]

#: the overrides above that are about another method than the default one
OTHER_METHOD = {"method.align=rotation": "method=iterative", "+method.align=rotation": "method=iterative",
                "method.solver.starts=2": "method=iterative", "+method.nonsense=1": "method=iterative"}


@pytest.fixture
def preflight_error(tiny_scene, tmp_path, monkeypatch):
    """``preflight_error(*overrides)``: the message the command line refuses them with."""
    monkeypatch.setattr(framework.run, "_claimed", None)

    def refuse(*overrides) -> str:
        with pytest.raises(ConfigError) as info:
            framework.run.preflight([f"scene.dir={tiny_scene}", f"cache.dir={tmp_path / 'c'}", *TINY,
                                     f"hydra.run.dir={tmp_path / 'run'}", *overrides])
        assert not (tmp_path / "run").exists()
        return str(info.value)
    return refuse


@pytest.mark.parametrize("override, message", SETTING_ERRORS, ids=[c[0] for c in SETTING_ERRORS])
def test_setting_errors(override, message, preflight_error):
    chosen = [OTHER_METHOD[override]] if override in OTHER_METHOD else []
    assert preflight_error(*chosen, override).startswith(message)


def test_cache_dir_errors(preflight_error, tiny_scene, tmp_path):
    (tmp_path / "file").write_text("")
    assert preflight_error(f"cache.dir={tmp_path / 'file'}") == (
        f"cache.dir={tmp_path / 'file'} is not a writable folder (it is a file): choose another cache.dir, "
        "or cache.dir=null to run without a cache")
    assert preflight_error(f"cache.dir={tmp_path / 'file' / 'sub'}").startswith(
        f"cache.dir={tmp_path / 'file' / 'sub'} is not a writable folder (Not a directory)")
    assert preflight_error(f"cache.dir={tiny_scene / 'cache'}") == (
        f"cache.dir={tiny_scene / 'cache'} is inside the scene folder {tiny_scene}, which runs never write "
        "to: choose a cache.dir outside it")
    assert not (tiny_scene / "cache").exists()


def test_cache_dir_unwritable(preflight_error, tmp_path):
    """A folder nobody can create: under /proc when running as root (root writes anywhere else),
    in a read-only folder otherwise."""
    if os.geteuid() == 0:
        target, why = "/proc/sir-cache/c", "No such file or directory"
    else:
        (tmp_path / "ro").mkdir(mode=0o500)
        target, why = str(tmp_path / "ro" / "c"), "Permission denied"
    assert preflight_error(f"cache.dir={target}").startswith(f"cache.dir={target} is not a writable folder ({why})")


def test_scene_dependent_errors(tmp_path):
    """Checks that need the scene: samples per view within Mitsuba's 32-bit limit, kernels present."""
    scene = make_tiny_scene(tmp_path / "tiny", kernels=("diffuse",))
    base = [f"scene.dir={scene}", "cache.dir=null", *TINY]
    with pytest.raises(ConfigError, match=r"^render.spp=4294967295 is too large for view view_0.png \(16x16 "
                       r"pixels\): Mitsuba renders at most 2\*\*32 - 1 samples per view, so use render.spp "
                       r"<= 16777215$"):
        prepare(compose([*base, "render.spp=4294967295"]))
    with pytest.raises(ConfigError, match=r"^method.kernels=\['specular'\] selects no weight of scene tiny, "
                       "whose kernels are diffuse: list at least one of them$"):
        prepare(compose([*base, "method.kernels=[specular]"]))




@pytest.mark.slow
@pytest.mark.parametrize("override", ["views=[]", "method=nonsense", "scene.dir=/tmp/ü"])
def test_cli_prints_one_line(override, tiny_scene, tmp_path):
    """The command line itself: the preflight line, status 2, no run folder at all."""
    message = dict(SETTING_ERRORS)[override]
    proc = cli([f"scene.dir={tiny_scene}", f"cache.dir={tmp_path / 'c'}", *TINY,
                 f"hydra.run.dir={tmp_path / 'run'}", override], tmp_path)
    assert error_line(proc) == f"error: {message}"
    assert not (tmp_path / "run").exists()


def _broken_scene(root: Path) -> Path:
    scene = make_tiny_scene(root)
    (scene / "meshes/block.ply").unlink()
    return scene


@pytest.mark.slow
def test_cli_failed_run_keeps_foreign_file(tmp_path):
    """A run folder holding someone's file is refused before anything runs; the file stays."""
    scene = _broken_scene(tmp_path / "broken")
    (tmp_path / "u").mkdir()
    (tmp_path / "u" / "keep").write_text("mine")
    proc = cli([f"scene.dir={scene}", f"hydra.run.dir={tmp_path / 'u'}", *TINY], tmp_path)
    assert error_line(proc) == (f"error: run folder {tmp_path / 'u'} (hydra.run.dir) already holds files "
                                 "(keep): choose a new or empty folder, so that this run's files cannot mix "
                                 "with others")
    assert sorted(p.name for p in (tmp_path / "u").iterdir()) == ["keep"]
    assert (tmp_path / "u" / "keep").read_text() == "mine"


@pytest.mark.slow
def test_cli_scene_folder_as_run_folder(tiny_scene, tmp_path):
    """``scene.dir=. hydra.run.dir=.`` inside a scene folder: refused, the scene untouched."""
    before = snapshot(tiny_scene)
    proc = cli(["scene.dir=.", "hydra.run.dir=.", f"cache.dir={tmp_path / 'c'}", *TINY], tiny_scene)
    assert error_line(proc) == (f"error: run folder {tiny_scene} (hydra.run.dir) is inside the scene folder "
                                 f"{tiny_scene}, which runs never write to: choose a run folder outside it")
    assert snapshot(tiny_scene) == before


@pytest.mark.slow
def test_cli_earlier_run_refused(tiny_scene, tmp_path):
    """A folder holding an earlier run's results.json is not reused: that run stays as it was."""
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "results.json").write_text("{}")
    proc = cli([f"scene.dir={tiny_scene}", f"hydra.run.dir={tmp_path / 'old'}", *TINY], tmp_path)
    assert error_line(proc).startswith(f"error: run folder {tmp_path / 'old'} (hydra.run.dir) holds an "
                                        "earlier run (results.json): choose a new or empty folder")
    assert [p.name for p in (tmp_path / "old").iterdir()] == ["results.json"]


@pytest.mark.slow
def test_cli_failed_run_in_empty_folder(tmp_path):
    """A run that fails in a folder that existed (empty) removes what it wrote, not the folder."""
    scene = _broken_scene(tmp_path / "broken")
    (tmp_path / "empty").mkdir()
    proc = cli([f"scene.dir={scene}", f"hydra.run.dir={tmp_path / 'empty'}", *TINY], tmp_path)
    assert error_line(proc).endswith("mesh file missing; fix the path in scene.yaml")
    assert list((tmp_path / "empty").iterdir()) == []


@pytest.mark.slow
def test_cli_interrupt(tiny_scene, tmp_path):
    """Ctrl-C while the method renders: ``interrupted`` (no traceback), status 130, no results.json,
    and the run folder this run created removed."""
    run_dir = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(Path(framework.run.__file__).parents[1]), PYTHONUNBUFFERED="1")
    args = [f"scene.dir={tiny_scene}", f"hydra.run.dir={run_dir}", "cache.dir=null", *TINY,
            "method=iterative", "budget.renders=100000", "method.noise=fixed",
            # no tolerance stops it: at 170 renders/s on the tiny scene (its kernels compiled once)
            # nlopt's tolerances ended the run within the second before the Ctrl-C
            "method.xtol_rel=0", "method.ftol_rel=0"]
    proc = subprocess.Popen([sys.executable, "-m", "framework.run", *args], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in proc.stdout:                     # Hydra logs to stdout: wait for the method to start
        if "method iterative on tiny" in line:
            break
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-2000:]
    assert [line for line in err.splitlines() if line.strip()][-1] == "interrupted"
    assert "Traceback" not in err
    assert not run_dir.exists()


@pytest.mark.parametrize("path", ["/tmp/a b,c=d", "/tmp/it's", "/tmp/a\\b", "/tmp/x${y}", "/tmp/ü[1]", "/tmp/end\\"])
def test_pinned_run_folder_survives_hydra_grammar(path):
    """The run folder preflight pins is handed to Hydra as a quoted override: any path reads back."""
    cfg = compose([f"hydra.run.dir={framework.run._quoted(Path(path))}"], hydra_config=True)
    assert cfg.hydra.run.dir == path
