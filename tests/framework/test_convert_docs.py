"""docs/convert.md's walk-through converts as written: its ``python -m framework.convert`` lines
run from a folder that sees the repository's ``scenes/`` (a symlink), and print what the text
says they print. (The ``framework.run`` lines are the runs tests/test_convert_accuracy.py makes
small.)"""
from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from framework.convert.__main__ import main

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "convert.md"


def _commands(marker: str) -> list[list[str]]:
    text = DOC.read_text()
    block = re.search(rf"<!-- {marker}-begin -->\n```sh\n(.*?)```\n<!-- {marker}-end -->", text, re.S).group(1)
    return [shlex.split(cmd) for cmd in block.replace("\\\n", " ").splitlines() if cmd.strip()]


@pytest.mark.slow
@pytest.mark.parametrize("marker, printed", [
    ("walkthrough", "city-from-cityjson: 15 segments, 218 triangles, 4 views, origin [652340.000, 6862275.000, 35.000]"),
    ("walkthrough-obj", "city-from-obj: 15 segments, 370 triangles, 4 views, origin [652340.000, 6862275.000, 35.000]"),
])
def test_walkthrough_converts(tmp_path, monkeypatch, capsys, marker, printed):
    (tmp_path / "scenes").symlink_to(ROOT / "scenes")
    monkeypatch.chdir(tmp_path)
    commands = _commands(marker)
    assert [c[:3] for c in commands] == [["python", "-m", "framework.convert"], ["python", "-m", "framework.run"]]
    assert main(commands[0][3:]) == 0
    out = capsys.readouterr()
    assert out.out.strip().endswith(printed) and out.err == ""
    assert printed in DOC.read_text().replace("\n", " ")
