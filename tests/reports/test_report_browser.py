"""Open the generated HTML in headless Chromium: every table present, every image loaded.

The pages carry an inline script that, on load, writes on <body> the image and table
counts and the images with naturalWidth == 0; ``--dump-dom`` gives us the result.
Screenshots go to ``.cache/test-artifacts/`` (``.cache/`` is ignored by git) for a person to
look at.
"""
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from reports import write_run_report
from reports.__main__ import main
from fakes import make_fake_run

ARTIFACTS = Path(__file__).resolve().parents[2] / ".cache" / "test-artifacts"
CHROMIUM_FLAGS = ("--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run",
                  "--disable-dev-shm-usage", "--hide-scrollbars")


def _chromium() -> str:
    exe = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if exe is None:
        pytest.fail("Chromium not found on PATH: install Debian's `chromium` package "
                    "(apt-get install chromium) to run the report browser tests")
    return exe


def _run_chromium(args, tmp_path) -> subprocess.CompletedProcess:
    cmd = [_chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'chromium-profile'}", *args]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail(f"Chromium did not finish within 60 s: {' '.join(cmd)}")
    if proc.returncode != 0:
        pytest.fail(f"Chromium failed to start (exit {proc.returncode}): {proc.stderr[-800:]}")
    return proc


def _page_check(html_path: Path, tmp_path) -> dict:
    """Body attributes set by the page's own check script after load."""
    proc = _run_chromium(["--virtual-time-budget=5000", "--dump-dom", html_path.resolve().as_uri()],
                         tmp_path)
    body = re.search(r"<body([^>]*)>", proc.stdout)
    assert body, f"no <body> in Chromium's DOM dump of {html_path}: {proc.stdout[:300]!r}"
    attrs = dict(re.findall(r'data-([a-z-]+)="([^"]*)"', body.group(1)))
    assert attrs.get("checked") == "yes", f"the page check script did not run: {attrs}"
    return attrs


def _screenshot(html_path: Path, name: str, tmp_path) -> Path:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    shot = ARTIFACTS / name
    shot.unlink(missing_ok=True)
    _run_chromium(["--virtual-time-budget=5000", f"--screenshot={shot}", "--window-size=1200,2000",
                   html_path.resolve().as_uri()], tmp_path)
    assert shot.is_file() and shot.stat().st_size > 10_000, f"no screenshot at {shot}"
    return shot


def _count(html_path: Path, pattern: str) -> int:
    return len(re.findall(pattern, html_path.read_text()))


@pytest.mark.slow
def test_run_report_in_browser(tmp_path):
    run = make_fake_run(tmp_path / "run", seed=0)
    _, html_path = write_run_report(run)
    attrs = _page_check(html_path, tmp_path)
    assert attrs["broken-images"] == "", f"images that did not load: {attrs['broken-images']}"
    assert int(attrs["image-count"]) == _count(html_path, r"<img ") == 7
    assert int(attrs["table-count"]) == _count(html_path, r"<table>") == 5      # with "where the time went"
    _screenshot(html_path, "run_report.png", tmp_path)


@pytest.mark.slow
def test_comparison_in_browser(fake_sweep, tmp_path):
    assert main([str(fake_sweep)]) == 0
    html_path = fake_sweep / "comparison.html"
    attrs = _page_check(html_path, tmp_path)
    assert attrs["broken-images"] == "", f"images that did not load: {attrs['broken-images']}"
    assert int(attrs["image-count"]) == _count(html_path, r"<img ") == 3
    assert int(attrs["table-count"]) == _count(html_path, r"<table>") == 3
    _screenshot(html_path, "comparison.png", tmp_path)


@pytest.mark.slow
def test_browser_check_catches_a_broken_image(tmp_path):
    run = make_fake_run(tmp_path / "run", correlation=False)
    _, html_path = write_run_report(run)
    (run / "report_files" / "convergence.png").unlink()
    attrs = _page_check(html_path, tmp_path)
    assert attrs["broken-images"] == "report_files/convergence.png"
