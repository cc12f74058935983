"""Issue 28, the comparison and the documentation: runs of two scenes that share a name are not
pooled (5), docs/cli.md lists every registered method and bundled scene (14), and a sweep's time
ratios leave out Dr.Jit's kernel compilation, which the first run of a process pays (17)."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from fakes import make_fake_run

from reports.compare import write_comparison

CLI_MD = Path(__file__).parents[2] / "docs" / "cli.md"


def _edit(run: Path, fn) -> Path:
    data = json.loads((run / "results.json").read_text())
    fn(data)
    (run / "results.json").write_text(json.dumps(data))
    return run


@pytest.mark.slow
def test_scenes_sharing_a_name_are_compared_apart(tmp_path):
    """Two scene folders named ``courtyard``, told apart by their content hash: two groups, each
    with its own reference column, and a note naming the shared name (was: one group, errors
    averaged over both)."""
    for i, digest in enumerate(("aaaa000011112222", "bbbb000011112222")):
        for seed in (0, 1):
            _edit(make_fake_run(tmp_path / "sweep" / f"{digest}_{seed}", seed=seed),
                  lambda d, h=digest: d["settings"].update(scene_hash=h))
    md, _ = write_comparison([tmp_path / "sweep"])
    text = md.read_text()
    assert "4 runs, 2 scene(s)" in text
    assert "## Scene courtyard, 1 view [aaaa000011112222]" in text
    assert "## Scene courtyard, 1 view [bbbb000011112222]" in text
    assert ("2 different scenes share the name courtyard, 1 view (content hashes or folders aaaa000011112222, "
            "bbbb000011112222): compared apart") in text


def test_run_records_the_scene_hash(tmp_path):
    """results.json ``settings.scene_hash`` is the scene's content hash (what the comparison
    groups by)."""
    from factory import compose_config, make_tiny_scene

    from framework.experiment import run_experiment
    from framework.render.backend import device_name
    from framework.scene import load_scene
    scene = make_tiny_scene(tmp_path / "tiny", n_views=1)
    results = run_experiment(compose_config(scene, "views=all", "render.spp=4", "observe.spp=8",
                                            "method.refine=0"), tmp_path / "run")
    assert results["settings"]["scene_hash"] == load_scene(scene).content_hash
    # 42: the device the run rendered on, beside its variant
    assert results["settings"]["device"] == device_name(results["settings"]["variant"])
    # 17: Dr.Jit's compilation is reported apart, and is part of the total
    assert 0.0 <= results["timings_s"]["compile"] <= results["timings_s"]["total"]
    assert results["timings_s"]["imports"] >= 0.0          # before the clock: not part of total


def _table_values(key: str) -> list[str]:
    row = next(line for line in CLI_MD.read_text().splitlines() if line.startswith(f"| `{key}` |"))
    return re.findall(r"`([^`]+)`", row.split("|")[2])


def test_cli_md_lists_every_method_and_scene():
    """The ``method=`` and ``scene=`` rows of docs/cli.md name every registered method and every
    bundled scene (the config groups the command line accepts), and nothing else; so does the
    list of ``python -m scenes.build``."""
    from framework.registry import available_methods
    from scenes.build import BUILDERS
    conf = Path(__file__).parents[2] / "framework" / "conf" / "scene"
    assert sorted(_table_values("method")) == available_methods()
    assert sorted(_table_values("scene")) == sorted(p.stem for p in conf.glob("*.yaml"))
    text = " ".join(CLI_MD.read_text().split())
    listed = re.search(r"or the `NAME`s among (.+?) \(an unknown name", text).group(1)
    assert sorted(re.findall(r"`([^`]+)`", listed)) == sorted(BUILDERS)


def _row(text: str, method: str) -> list[str]:
    """The cells of ``method``'s row of the comparison's summary table."""
    line = next(ln for ln in text.splitlines() if ln.startswith(f"| {method} | 2 |"))
    return [c.strip() for c in line.strip("|").split("|")]


@pytest.mark.slow
def test_time_ratio_leaves_out_compilation(tmp_path):
    """The first symbolic run pays 2.5 s of compilation and 0.25 s of observations (3.75 s total,
    1.0 s of work), the second 0.25 s of compilation (1.25 s total, 1.0 s of work): against a
    method taking 1.25 s with neither, the ratio of totals is ×0.5 (1.25 / 2.5), the ratio of the
    work ×1.25; the table shows both and says what they are. Numbers read back from the table
    within 1e-9 relative (the printed ones are rounded)."""
    for seed, (total, compile_s, observe) in enumerate(((3.75, 2.5, 0.25), (1.25, 0.25, 0.0))):
        _edit(make_fake_run(tmp_path / "sweep" / f"s{seed}", seed=seed),
              lambda d, t=total, c=compile_s, o=observe: d["timings_s"].update(total=t, compile=c, observe=o))
        _edit(make_fake_run(tmp_path / "sweep" / f"i{seed}", method="iterative", seed=seed),
              lambda d: d["timings_s"].update(total=1.25, compile=0.0, observe=0.0))
    text = write_comparison([tmp_path / "sweep"])[0].read_text()
    assert ("| Total time (s) | Compile (s) | Work (s) | Renders | Time / symbolic | Work / symbolic | "
            "Renders / symbolic |") in text
    symbolic, iterative = _row(text, "symbolic"), _row(text, "iterative")
    assert float(symbolic[4].split(" ± ")[0]) == pytest.approx(2.5, rel=1e-9)
    assert float(symbolic[5].split(" ± ")[0]) == pytest.approx(1.375, rel=1e-9)
    assert float(symbolic[6].split(" ± ")[0]) == pytest.approx(1.0, rel=1e-9)
    assert float(iterative[8].lstrip("×")) == pytest.approx(0.5, rel=1e-9)
    assert float(iterative[9].lstrip("×")) == pytest.approx(1.25, rel=1e-9)
    assert "Compile: Dr.Jit's kernel compilation" in text and "Work: the total less compile" in text


@pytest.mark.parametrize("key", ["method", "scene"])
def test_table_parser_reads_the_rows(key):
    """The rows the test above reads exist and hold several names (a renamed row would make it
    vacuous)."""
    assert len(_table_values(key)) >= 5
