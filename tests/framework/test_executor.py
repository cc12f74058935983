"""Executors: serial (default) and dask.distributed (2-worker LocalCluster, 1 thread each)."""
from __future__ import annotations

import numpy as np
import pytest
from omegaconf import OmegaConf

from framework.errors import ConfigError
from framework.executor import SerialExecutor, make_executor
from factory import make_problem, make_tiny_scene, run_symbolic


def test_make_executor_defaults_and_errors():
    assert isinstance(make_executor(None), SerialExecutor)
    assert make_executor(OmegaConf.create({"name": "serial"})).name == "serial"
    with pytest.raises(ConfigError, match="executor=spark"):
        make_executor(OmegaConf.create({"name": "spark"}))
    with pytest.raises(ConfigError, match="executor.n_workers=0"):
        make_executor(OmegaConf.create({"name": "dask", "n_workers": 0}))


@pytest.mark.slow
def test_dask_local_cluster_equals_serial_and_fills_cache(tmp_path):
    """Two worker processes render the two views (same seeds per view): the estimates equal the
    serial run's within 1e-6 relative (only the summation order of the Gram systems may differ);
    the driver stores the workers' views in the cache, so a serial rerun reads both from it and
    gives the same estimates."""
    root = make_tiny_scene(tmp_path / "s", kernels=("diffuse",))
    serial = run_symbolic(make_problem(root))
    cache = f"cache.dir={tmp_path / 'cache'}"
    dask = run_symbolic(make_problem(root, None, "executor=dask", "executor.n_workers=2",
                                     "executor.threads_per_worker=1", cache))
    assert dask.extras["executor"] == "dask" and dask.extras["views_from_cache"] == []
    np.testing.assert_allclose(dask.estimate, serial.estimate, rtol=1e-6)
    np.testing.assert_allclose(dask.std, serial.std, rtol=1e-6)
    again = run_symbolic(make_problem(root, None, cache))
    assert sorted(again.extras["views_from_cache"]) == ["view_0.png", "view_1.png"]
    np.testing.assert_allclose(again.estimate, serial.estimate, rtol=1e-6)


def test_tree_sum_association_and_memory():
    """TreeSum adds like a binary counter: ((a+b)+(c+d))+e for five values, checked on strings
    (their '+' shows the association), at most log2(n) + 1 partial sums held, exact on numbers."""
    from framework.executor import TreeSum

    class Expr(str):
        def __add__(self, other):
            return Expr(f"({self}+{other})")

    t = TreeSum()
    assert t.total(empty="none") == "none"
    held = []
    for v in "abcde":
        t.add(Expr(v))
        held.append(len(t._partial))
    assert t.total() == "(((a+b)+(c+d))+e)"
    assert held == [1, 1, 2, 1, 2]
    t = TreeSum()
    for v in range(1, 101):
        t.add(v)
        assert len(t._partial) <= int(np.log2(v)) + 1
    assert t.total() == 5050


def test_executor_options_errors():
    """One line each, naming the key and the fix (:mod:`framework.executor_options`)."""
    from framework.executor_options import DaskOptions, SerialOptions, executor_options
    assert executor_options(None) == SerialOptions() and executor_options({"name": "dask"}) == DaskOptions()
    with pytest.raises(ConfigError, match=r"executor.n_workers is not an option of executor=serial \(its options: "
                                          r"none\); executor=dask has it"):
        executor_options({"name": "serial", "n_workers": 2})
    with pytest.raises(ConfigError, match=r"executor.workers is not an option of executor=dask"):
        executor_options({"name": "dask", "workers": 2})
    with pytest.raises(ConfigError, match=r"executor.threads_per_worker=0 is out of range"):
        executor_options({"name": "dask", "threads_per_worker": 0})
    with pytest.raises(ConfigError, match=r"executor.address=localhost:8786 is not a scheduler address"):
        executor_options({"name": "dask", "address": "localhost:8786"})
    with pytest.raises(ConfigError, match=r"executor=3 is not a mapping"):
        executor_options(3)
