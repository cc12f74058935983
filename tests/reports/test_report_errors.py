"""reports on bad input: one stderr line naming the path and the fix, exit 2, no output."""
import json

import pytest

from reports import ReportError, write_run_report
from reports.__main__ import main
from fakes import make_fake_run


def _assert_refused(argv, capsys, path_text, out_dir):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and path_text in err, err
    assert not (out_dir / "comparison.md").exists() and not (out_dir / "comparison.html").exists()


def test_missing_folder(tmp_path, capsys):
    _assert_refused([str(tmp_path / "nope"), "--out", str(tmp_path)], capsys, "nope", tmp_path)


def test_folder_without_results(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    _assert_refused([str(tmp_path / "empty")], capsys, "no results.json", tmp_path / "empty")


def test_unreadable_json(tmp_path, capsys):
    run = make_fake_run(tmp_path / "sweep" / "run")
    (run / "results.json").write_text("{not json")
    _assert_refused([str(tmp_path / "sweep")], capsys, "unreadable JSON", tmp_path / "sweep")
    assert not (run / "report.html").exists()


def test_json_missing_keys(tmp_path, capsys):
    run = make_fake_run(tmp_path / "run")
    (run / "results.json").write_text(json.dumps({"method": "symbolic"}))
    _assert_refused([str(run)], capsys, "missing key(s) scene, channels, parameters", run)


def test_json_not_an_object(tmp_path, capsys):
    run = make_fake_run(tmp_path / "run")
    (run / "results.json").write_text("[1, 2]")
    _assert_refused([str(run)], capsys, "expected a JSON object", run)


def test_one_bad_run_among_good_ones_writes_nothing(tmp_path, capsys):
    good = make_fake_run(tmp_path / "sweep" / "good")
    bad = make_fake_run(tmp_path / "sweep" / "bad")
    (bad / "results.json").write_text("")
    _assert_refused([str(tmp_path / "sweep")], capsys, str(bad / "results.json"), tmp_path / "sweep")
    assert not (good / "report.html").exists()


def test_no_arguments_is_usage_error(capsys):
    assert main([]) == 2
    assert "usage" in capsys.readouterr().err


def test_write_run_report_raises(tmp_path):
    with pytest.raises(ReportError, match="not found"):
        write_run_report(tmp_path)
    (tmp_path / "results.json").write_text("{")
    with pytest.raises(ReportError, match="unreadable JSON"):
        write_run_report(tmp_path)
    assert not (tmp_path / "report.md").exists()
