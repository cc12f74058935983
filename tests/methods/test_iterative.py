"""The plain iterative baseline (methods/iterative) and the shared pieces (methods/_common.py), on
the 16x16 tiny scene (the solvers' own tests: tests/framework/test_optim.py).

Problems come from tests/factory.py.
"""
from __future__ import annotations

import numpy as np
import pytest
from factory import fresh_weights, kernels_per_call, max_error, method_config, run_iterative, tiny_problem

from framework.errors import ConfigError
from methods._common import RenderLedger
from methods.iterative import IterativeMethod, _Objective


def expected_renders(result, D: int) -> int:
    """Forward differences: D + 1 renders per evaluation with gradient, 1 without, + 1 final."""
    n_grad, n_eval = result.extras["gradient_evaluations"], result.extras["evaluations"]
    return n_grad * (D + 1) + (n_eval - n_grad) + 1


@pytest.mark.slow
def test_iterative_recovers_diffuse(tmp_path):
    """Fixed noise (common random numbers), forward FD, 64 spp: |ρ - ρ_ref| <= 0.05.

    Tolerance source: max error measured over seeds 0-5 (``tiny_problem(seed=s)``: observation
    stream and run seed): 0.019-0.033 (seed 0: 0.021); forward differences shift the optimum by
    about step/2 = 0.01, plus Monte-Carlo noise at 64 vs 256 spp. 0.05 = 1.5x the worst seed.
    """
    problem = tiny_problem(tmp_path / "s", spp=64, budget=200)
    result = run_iterative(problem, noise="fixed")
    assert max_error(problem, result) <= 0.05
    assert result.renders <= 200
    assert result.renders == expected_renders(result, D=len(problem.parameters))
    assert len(result.cost_history) == len(result.cost_times_s) == result.extras["evaluations"]
    assert min(result.cost_history) < result.cost_history[0]
    assert set(result.reconstructions) == {c.name for c in problem.cameras}
    assert result.reconstructions[problem.cameras[0].name].shape == (16, 16, 3)
    assert set(result.timings_s) >= {"render", "solve"}


def test_iterative_budget_stop(tmp_path):
    """A small budget stops cleanly (FORCED_STOP) within it, keeping one render for the end."""
    problem = tiny_problem(tmp_path / "s", budget=10)
    result = run_iterative(problem, noise="fresh")
    D = len(problem.parameters)
    assert result.renders <= 10
    assert result.renders == expected_renders(result, D)
    assert result.extras["status"] == "FORCED_STOP"
    assert result.reconstructions


def test_iterative_budget_too_small_keeps_guess(tmp_path):
    """With no room for one gradient, the estimate is the guess and only the final render is spent."""
    problem = tiny_problem(tmp_path / "s", budget=3)
    result = run_iterative(problem, guess=0.3)
    assert result.renders == 1
    np.testing.assert_allclose(result.estimate, 0.3)
    assert result.extras["status"] == "BUDGET_TOO_SMALL"


def test_iterative_central_counts(tmp_path):
    """Central differences: 2D + 1 renders per evaluation with gradient; max_eval limits evaluations."""
    problem = tiny_problem(tmp_path / "s", budget=100)
    result = run_iterative(problem, fd="central", max_eval=3, noise="fixed")
    D = len(problem.parameters)
    n_grad, n_eval = result.extras["gradient_evaluations"], result.extras["evaluations"]
    assert n_eval <= 3
    assert result.renders == n_grad * (2 * D + 1) + (n_eval - n_grad) + 1


def test_iterative_compiles_once_for_all_weights(tmp_path):
    """20 passes at fresh random weights and fresh seeds compile no kernel after the first: the
    weights reach Mitsuba as opaque values (as literals, every pass compiled its render kernel)."""
    problem = tiny_problem(tmp_path / "s", kernels=("diffuse", "specular"), budget=20, obs_spp=16)
    options = IterativeMethod(method_config("iterative", noise="fresh")).options
    objective = _Objective(problem, RenderLedger(20, desc="test"), options)
    counts = kernels_per_call(objective.render, fresh_weights(problem, 20))
    assert sum(counts[1:]) == 0, counts


@pytest.mark.parametrize("key, value", [
    ("fd", "backward"), ("step", 0), ("step", 0.7), ("step", "big"), ("noise", "random"),
    ("algorithm", "LD_FOO"), ("max_eval", -1), ("max_eval", 2.5), ("xtol_rel", -1.0), ("ftol_rel", -1e-3),
    ("init", "magic"), ("guess", 1.5), ("guess", {"specular": 0.1}), ("guess", "half"),
])
def test_iterative_errors(tmp_path, key, value):
    """Each bad option raises ConfigError naming the key."""
    problem = tiny_problem(tmp_path / "s", budget=5)
    with pytest.raises(ConfigError, match=f"method.{key}="):
        run_iterative(problem, **{key: value})


def test_iterative_errors_unconstrained_algorithm(tmp_path):
    """LD_LBFGS refuses the Σρ <= 1 constraints of a segment with two kernels (nlopt 2.11 raises)."""
    problem = tiny_problem(tmp_path / "s", kernels=("diffuse", "specular"), budget=5, obs_spp=16)
    with pytest.raises(ConfigError, match="method.algorithm=LD_LBFGS"):
        run_iterative(problem, algorithm="LD_LBFGS")


# ------------------------------------------------------------------------------------------------
# framework/optim.py and methods/_common.py
# ------------------------------------------------------------------------------------------------
def test_iterative_init_lambertian_prior(tmp_path):
    """init: lambertian_prior starts from that method's diffuse estimates; its renders count.

    |ρ - ρ_ref| <= 0.1: max error measured over seeds 0-5 (``tiny_problem(seed=s)``, 64-spp
    observations): 0.007-0.059 (seed 0: 0.023); 0.1 = 1.7x the worst seed."""
    problem = tiny_problem(tmp_path / "s", budget=4, obs_spp=64)
    result = run_iterative(problem, init="lambertian_prior")
    assert 2 <= result.renders <= 4
    assert max_error(problem, result) <= 0.1
