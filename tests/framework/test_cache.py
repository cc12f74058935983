"""The on-disk cache: an entry comes back as stored, and a damaged one is missing, never trusted."""
from __future__ import annotations

import numpy as np
import pytest

from framework.cache import Cache

KEY = {"scene": "s", "view": "v", "spp": 4}


def _entry(tmp_path):
    cache = Cache(tmp_path)
    arrays = {"data": np.arange(50_000, dtype=np.float64), "indptr": np.arange(7, dtype=np.int32)}
    cache.store("tile", KEY, arrays)
    return cache, arrays


def test_entry_comes_back_as_stored(tmp_path):
    cache, arrays = _entry(tmp_path)
    back = cache.load("tile", KEY)
    assert sorted(back) == sorted(arrays)
    for name, a in arrays.items():
        assert back[name].dtype == a.dtype and np.array_equal(back[name], a)
    assert cache.load("tile", {**KEY, "spp": 8}) is None


@pytest.mark.parametrize("where", [0.01, 0.5, 0.999])
def test_damaged_entry_is_missing(tmp_path, where):
    """One flipped byte at the start, middle or end of the file (a header, the large array, the
    small one or the zip's directory): the load fails (the arrays' CRC-32) and says None."""
    cache, _ = _entry(tmp_path)
    path = cache.path("tile", KEY)
    data = bytearray(path.read_bytes())
    data[int(where * (len(data) - 1))] ^= 0xFF
    path.write_bytes(bytes(data))
    assert cache.load("tile", KEY) is None


def test_truncated_entry_is_missing(tmp_path):
    cache, _ = _entry(tmp_path)
    path = cache.path("tile", KEY)
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    assert cache.load("tile", KEY) is None


def test_entry_of_an_earlier_version_loads_without_its_checksum(tmp_path):
    """Entries stored with a ``__checksum__`` member (earlier versions) stay valid: it is skipped."""
    cache = Cache(tmp_path)
    path = cache.path("tile", KEY)
    path.parent.mkdir(parents=True)
    np.savez(path, __checksum__=np.array("0" * 64), data=np.ones(3))
    assert list(cache.load("tile", KEY)) == ["data"]


def _package(root, name, files):
    for rel, text in files.items():
        (root / name / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / name / rel).write_text(text)


def test_code_version_follows_the_named_code(tmp_path, monkeypatch):
    """An edit anywhere below a named package, or of a named module, changes the digest; an edit
    of code not named does not (fresh module names per test: ``code_version`` is memoised)."""
    from framework.cache import code_version
    _package(tmp_path, "cv_pkg", {"__init__.py": "", "sub/__init__.py": "", "sub/deep.py": "x = 1\n"})
    _package(tmp_path, "cv_other", {"__init__.py": "y = 1\n"})
    monkeypatch.syspath_prepend(str(tmp_path))
    before = code_version("cv_pkg")
    assert code_version("cv_pkg") == before and len(before) == 16
    (tmp_path / "cv_other" / "__init__.py").write_text("y = 2\n")
    code_version.cache_clear()
    assert code_version("cv_pkg") == before
    (tmp_path / "cv_pkg" / "sub" / "deep.py").write_text("x = 2\n")
    code_version.cache_clear()
    assert code_version("cv_pkg") != before
    assert code_version("cv_pkg.sub.deep") != code_version("cv_pkg")


def test_code_version_errors():
    from framework.cache import code_version
    with pytest.raises(ValueError, match="no_such_module_here"):
        code_version("no_such_module_here")
