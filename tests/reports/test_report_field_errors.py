"""reports on a results.json whose fields have the wrong type: one line ``error: ...`` naming the
file and the field, exit 2, and the user's folder exactly as it was (no partial report)."""
import json

import pytest
from factory import snapshot
from fakes import make_fake_run

import reports.run
from reports import ReportError, write_run_report
from reports.__main__ import main

BAD_FIELDS = [
    (lambda d: d["parameters"][0].update(estimate=["a", "b", "c"]),
     "parameters[0].estimate must be 3 finite numbers (one per channel: R, G, B; null where unknown) or null, "
     "got ['a', 'b', 'c']"),
    # a NaN (JSON's NaN, which Python reads) and too few channels: the report was written before
    (lambda d: d["parameters"][0].update(estimate=[float("nan"), 0.5, 0.5]),
     "parameters[0].estimate must be 3 finite numbers (one per channel: R, G, B; null where unknown) or null, "
     "got [nan, 0.5, 0.5]"),
    (lambda d: d["parameters"][1].update(estimate=[0.5, 0.5]),
     "parameters[1].estimate must be 3 finite numbers (one per channel: R, G, B; null where unknown) or null, "
     "got [0.5, 0.5]"),
    (lambda d: d.update(image_rmse=float("inf")), "image_rmse must be a number or null, got inf"),
    (lambda d: d.update(cost_times_s=["1s", "2s"]), "cost_times_s must be a list of numbers"),
    (lambda d: d.update(timings_s={"total": "fast"}), "timings_s must be an object of numbers"),
    (lambda d: d["correlation"].update(matrix=[[1, 0], [0]]), "correlation.matrix must be a 2 x 2 list of numbers"),
    (lambda d: d.update(trace=[{"time_s": 0.1, "renders": 1, "estimate": [[0.5]]}]),
     "trace[0].estimate must be 3 lists (one per parameter) of 3 numbers"),
    (lambda d: d.update(views="v0.png"), "views must be a list of objects"),
]


@pytest.mark.parametrize("edit, message", BAD_FIELDS, ids=[m.split(" ")[0] for _, m in BAD_FIELDS])
def test_bad_field_refused(edit, message, tmp_path, capsys):
    run = make_fake_run(tmp_path / "run")
    data = json.loads((run / "results.json").read_text())
    edit(data)
    (run / "results.json").write_text(json.dumps(data))
    before = snapshot(tmp_path)
    assert main([str(run)], prog="python -m framework.report") == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err] and err.startswith(f"error: {run / 'results.json'}: {message}"), err
    assert snapshot(tmp_path) == before


@pytest.mark.slow
def test_failing_report_writes_nothing(tmp_path, monkeypatch):
    """A report that fails half-way leaves the earlier report as it was, and no new file."""
    run = make_fake_run(tmp_path / "run")
    write_run_report(run)
    before = snapshot(run)

    def fail(doc, ctx):
        raise ReportError("stop")
    monkeypatch.setattr(reports.run, "_section_relit", fail)
    with pytest.raises(ReportError, match="stop"):
        write_run_report(run)
    assert snapshot(run) == before


def test_unwritable_out(tmp_path, capsys):
    run = make_fake_run(tmp_path / "run")
    (tmp_path / "file").write_text("")
    assert main([str(run), "--out", str(tmp_path / "file" / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"error: cannot write the report in {tmp_path / 'file' / 'out'} (Not a directory): "
                   "choose a writable folder with --out")
