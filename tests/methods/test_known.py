"""Known weights (scene.yaml ``known``: a calibration panel) in the symbolic family
(methods/symbolic/survey/known.py): substituted in the solve, reported with ``"known": true``."""
import dataclasses
import logging

import numpy as np
import pytest
import scipy.sparse as sp

from factory import compose_config, edit_scene_yaml, make_tiny_scene, quad, run_method, tiny_problem
from framework.errors import ConfigError
from framework.scene.model import Photometry
from methods.symbolic.survey.known import Substitution, known_guess
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.coefficients import ViewCoefficients
from methods.symbolic.system.gram import GramSystem
from methods.symbolic.trace.monomial_codes import all_codes

GAINS = np.array([1.5, 0.8, 1.2])      # view_1's gains per channel; view_0 is the reference


# ------------------------------------------------------------------------------------------------
# The substitution by hand
# ------------------------------------------------------------------------------------------------
def _random_polynomials(rng, D, N, n, C):
    """``n`` pixels of random polynomials over every monomial of degree <= N in D parameters:
    their two half-sample coefficient matrices per channel, the observations and the basis."""
    basis = MonomialBasis(D, N)
    A = [sp.csr_matrix(rng.normal(size=(n, basis.size))) for _ in range(C)]
    B = [sp.csr_matrix(rng.normal(size=(n, basis.size))) for _ in range(C)]
    y = rng.normal(size=(n, C))
    return basis, A, B, y


def test_substitution_by_hand_two_parameters():
    """ρ = (ρ0, ρ1), N_max = 2: monomials 1, ρ0, ρ1, ρ0², ρ0ρ1, ρ1². With ρ0 = k known (one value
    per channel) every pixel's polynomial in ρ1 alone equals the full one at (k, ρ1), written
    out by hand: γ1 + γ2 k + γ4 k² + (γ3 + γ5 k) ρ1 + γ6 ρ1²; the mapped system's cost equals
    the full cost, and G' = MᵀGM, b' = Mᵀb equal the cross Gram of the mapped coefficients.
    Exact up to rounding: 1e-12 relative."""
    rng = np.random.default_rng(0)
    basis, A, B, y = _random_polynomials(rng, 2, 2, 7, 2)
    k = np.array([0.3, 0.7])
    sub = Substitution.build(basis.codes, 2, 2, np.array([k, [np.nan, np.nan]]))
    free = sub.basis()
    assert sub.n_free == 1 and free.size == 3                   # 1, ρ1, ρ1²
    view = ViewCoefficients(A, B, 0.5, basis.codes)
    (_, mapped), = sub.view(view).blocks()
    for c in range(2):
        g = A[c].toarray()
        # the basis' order: codes sorted by degree, then the largest parameter
        order = [basis.index(m) for m in ([], [0], [1], [0, 0], [0, 1], [1, 1])]
        g1, g2, g3, g4, g5, g6 = (g[:, j] for j in order)
        for r1 in (0.0, 0.25, 0.9):
            by_hand = g1 + g2 * k[c] + g4 * k[c] ** 2 + (g3 + g5 * k[c]) * r1 + g6 * r1 ** 2
            full = A[c] @ basis.evaluate(np.array([k[c], r1]))
            mine = mapped.a[c] @ free.evaluate(np.array([r1]))
            np.testing.assert_allclose(full, by_hand, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(mine, full, rtol=1e-12, atol=1e-12)
    system = GramSystem.zeros(basis.codes, 2).accumulate_sparse(A, y, B)
    reduced = sub.system(system)
    direct = GramSystem.zeros(free.codes, 2).accumulate_sparse(mapped.a, y, mapped.b)
    for c in range(2):
        np.testing.assert_allclose(reduced.G[c].toarray(), direct.G[c].toarray(), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(reduced.b, direct.b, rtol=1e-12, atol=1e-12)
    for r1 in (0.1, 0.6):
        full_mu = np.stack([basis.evaluate(np.array([k[c], r1])) for c in range(2)])
        free_mu = np.stack([free.evaluate(np.array([r1])) for _ in range(2)])
        np.testing.assert_allclose(reduced.cost(free_mu), system.cost(full_mu), rtol=1e-12)


def test_mapped_view_lifts_instead_of_mapping_its_blocks():
    """A view mapped to the free monomials is predicted and scored through its own coefficients
    with ``μ`` and ``J`` lifted (``(A M) x = A (M x)``): the same pixel values and sandwich meat,
    with and without clusters, as coefficients mapped block by block (materialised), to 1e-12
    relative (only the order of the products differs); a tiled view of two blocks."""
    from methods.symbolic.system.coefficients import TiledCoefficients, predicted
    from methods.symbolic.uncertainty.sandwich_meat import score_meat
    rng = np.random.default_rng(3)
    basis, A, B, y = _random_polynomials(rng, 3, 2, 9, 2)
    values = np.array([[np.nan, np.nan], [0.4, 0.6], [np.nan, np.nan]])
    sub = Substitution.build(basis.codes, 3, 2, values, np.array([[1.0, 1.0], [1.0, 1.0], [0.5, 0.3]]))
    view = TiledCoefficients([0, 4], [ViewCoefficients([m[:4] for m in A], [m[:4] for m in B], 0.5, basis.codes),
                                      ViewCoefficients([m[4:] for m in A], [m[4:] for m in B], 0.5, basis.codes)], 9)
    lifted = sub.view(view)
    materialised = TiledCoefficients([0, 4], [block for _, block in lifted.blocks()], 9)
    free = sub.basis()
    rho = rng.uniform(0.2, 0.8, (free.n_params, 2))
    mu = np.stack([free.evaluate(rho[:, c]) for c in range(2)])
    np.testing.assert_allclose(predicted(lifted, mu, free.codes), predicted(materialised, mu, free.codes),
                               rtol=1e-12, atol=1e-12)
    columns = np.arange(free.size)
    for clusters in (None, [np.array([0, 0, 1, 1, 1, 2, 2, 3, 3])]):
        meat = score_meat(free, rho, [(lifted, y)], columns, free.codes, clusters=clusters)
        expected = score_meat(free, rho, [(materialised, y)], columns, free.codes, clusters=clusters)
        np.testing.assert_allclose(meat, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())


def test_substitution_renumbers_and_scales_the_free_weights():
    """Three parameters, N_max = 3, the middle one known: the free ones are renumbered (0, 2 ->
    0, 1), and a free weight solved as z = ρ / s (s: what its segment's known kernels leave)
    gives the full polynomial at ρ = s z. Checked on every monomial of degree <= 3."""
    rng = np.random.default_rng(1)
    basis, A, _, _ = _random_polynomials(rng, 3, 3, 5, 1)
    values = np.array([[np.nan], [0.4], [np.nan]])
    scale = np.array([[1.0], [1.0], [0.6]])              # parameter 2 shares a segment with the known one
    sub = Substitution.build(basis.codes, 3, 3, values, scale)
    assert list(sub.free) == [0, 2] and np.array_equal(sub.codes, all_codes(2, 3))
    (_, mapped), = sub.view(ViewCoefficients(A, None, 1.0, basis.codes)).blocks()
    for z in ([0.2, 0.5], [0.9, 0.1], [0.0, 1.0]):
        rho = sub.expand(np.array(z)[:, None])[:, 0]
        assert rho[1] == 0.4 and np.isclose(rho[2], 0.6 * z[1])
        np.testing.assert_allclose(mapped.a[0] @ sub.basis().evaluate(np.array(z)), A[0] @ basis.evaluate(rho),
                                   rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(sub.reduce(np.array([[0.3], [0.4], [0.3]])), [[0.3], [0.5]])


# ------------------------------------------------------------------------------------------------
# The tiny scene
# ------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    """Two views of the tiny diffuse scene (ground + block), 16 spp, observations at 256 spp."""
    return tiny_problem(tmp_path_factory.mktemp("known"), n_views=2, spp=16)


def _with_known(problem, segment=0):
    """``problem`` with segment ``segment``'s diffuse weight known at its reference (the
    observations, rendered at the references, do not change)."""
    segs = list(problem.scene.segments)
    segs[segment] = dataclasses.replace(segs[segment], known={"diffuse": segs[segment].reference["diffuse"]})
    return dataclasses.replace(problem, scene=dataclasses.replace(problem.scene, segments=tuple(segs)))


@pytest.mark.parametrize("method", ["symbolic", "lambertian_prior"])
def test_known_ground_leaves_the_block_where_the_free_fit_has_it(problem, method):
    """The ground's diffuse known at its reference: the block's estimates agree with the run
    where the ground is free within 4 std + 0.005 (the runs share the observations and the seed,
    not the kernel selection: their difference is Monte Carlo noise of at most about √2 std, plus
    what the ground's error moved through the light it throws on the block; measured 0.003
    symbolic (joint), 0.011 lambertian_prior (per segment), std 0.012-0.025), and the block
    within 4 std + 0.005 of its reference. The known weight comes back as its value, std 0,
    observable, not ill-determined, and results.json marks it ``"known": true``."""
    from framework.results import parameter_rows
    known = _with_known(problem)
    free, held = run_method(method, problem), run_method(method, known)
    ref = problem.scene.reference(problem.parameters)
    tol = 4 * free.std[1] + 0.005
    assert (np.abs(held.estimate[1] - free.estimate[1]) < tol).all(), (held.estimate, free.estimate, free.std)
    assert (np.abs(held.estimate[1] - ref[1]) < 4 * held.std[1] + 0.005).all(), (held.estimate, held.std)
    np.testing.assert_array_equal(held.estimate[0], ref[0])
    np.testing.assert_array_equal(held.std[0], 0.0)
    assert held.observable[0] and held.extras["ill_determined"] == [False, False]
    rows = parameter_rows(known, held)
    assert rows[0]["known"] is True and rows[0]["std"] == [0.0, 0.0, 0.0] and rows[0]["estimate"] == list(ref[0])
    assert "known" not in rows[1]
    assert "known" not in parameter_rows(problem, free)[0]
    assert held.extras["correlation"]["labels"] == ["block/diffuse"]
    assert held.extras["initial_guess"][0] == list(ref[0])          # a known weight starts at its value


def test_known_panel_with_per_view_gains(problem):
    """view_1 photographed with GAINS, ``exposure: per_view`` (view_0 the reference, its gains 1),
    the ground known: the gains come back within 4 std of GAINS and the block within 4 std + 0.005
    of its reference and of the same per-view fit with the ground free (the reference view fixes
    the gauge either way; the known panel adds the panel's pixels of both views as calibrated
    data). Measured (seed 0): gains 1.512, 0.806, 1.205 (std 0.020, 0.009, 0.007); block
    0.3117, 0.6219, 0.5274 (std 0.014, 0.030, 0.016) against 0.3118, 0.6215, 0.5271 with the
    ground free."""
    names = [c.name for c in problem.cameras]
    observed = {**problem.observed, names[1]: problem.observed[names[1]] * GAINS}

    def per_view(p):
        scene = dataclasses.replace(p.scene, photometry=Photometry(exposure="per_view", reference_view=names[0]))
        return dataclasses.replace(p, scene=scene, observed=observed)

    free = run_method("symbolic", per_view(problem), robust="none")
    held = run_method("symbolic", per_view(_with_known(problem)), robust="none")
    ref = problem.scene.reference(problem.parameters)
    gains = {e["view"]: e for e in held.extras["exposure"]}
    est, std = np.array(gains[names[1]]["estimate"]), np.array(gains[names[1]]["std"])
    assert gains[names[0]]["reference"] and (std > 0).all()
    assert (np.abs(est - GAINS) < 4 * std).all(), (est, std)
    assert (np.abs(held.estimate[1] - ref[1]) < 4 * held.std[1] + 0.005).all(), (held.estimate, held.std)
    assert (np.abs(held.estimate[1] - free.estimate[1]) < 4 * free.std[1] + 0.005).all()
    np.testing.assert_array_equal(held.estimate[0], ref[0])


def test_known_segment_no_view_sees_warns(tmp_path, caplog):
    """A known panel under the ground (no view sees it): one warning line naming it, and the run
    goes on; the known ground, which the views see, gives none."""
    from framework.experiment import prepare
    from framework.scene.write import write_mesh
    root = make_tiny_scene(tmp_path / "s", kernels=("diffuse",))
    write_mesh(root / "meshes/panel.ply", *quad(-0.5, 0.5, -0.5, 0.5, z=-1.0))
    edit_scene_yaml(root, lambda d: d["segments"].append(
        {"name": "panel", "meshes": ["meshes/panel.ply"], "kernels": ["diffuse"], "known": {"diffuse": 0.5}}))
    edit_scene_yaml(root, lambda d: d["segments"][0].update(known={"diffuse": [0.5, 0.4, 0.3]}))
    with caplog.at_level(logging.WARNING, logger="methods.symbolic.survey.known"):
        problem, method, _ = prepare(compose_config(root, "views=all"))
    lines = [r.getMessage() for r in caplog.records if r.name == "methods.symbolic.survey.known"]
    assert len(lines) == 1 and "'panel'" in lines[0] and "\n" not in lines[0], lines
    result = method.run(problem)
    assert result.estimate[2].tolist() == [0.5, 0.5, 0.5] and np.isfinite(result.estimate[1]).all()


@pytest.mark.parametrize("name", ["iterative", "differentiable"])
def test_baselines_refuse_known(tmp_path, name):
    """The render-in-the-loop baselines do not treat ``known``: one line, before any render."""
    from framework.experiment import prepare
    root = make_tiny_scene(tmp_path / "s")
    edit_scene_yaml(root, lambda d: d["segments"][1].update(known={"diffuse": [0.3, 0.6, 0.5]}))
    match = (rf"scene.yaml: segment 'block' known \(diffuse\) is not supported by method={name} yet; remove known "
             r"\(give the values as the segment's reference to compare the estimates with them\)$")
    with pytest.raises(ConfigError, match=match) as info:
        prepare(compose_config(root, "views=all", f"method={name}"))
    assert "\n" not in str(info.value)


def test_free_kernel_of_a_known_segment_uses_what_the_known_one_leaves(tmp_path):
    """Diffuse + specular, the ground's diffuse known at [0.5, 0.4, 0.3]: the ground's specular is
    solved within 1 - known diffuse (exact constraint of the substitution, z = ρ / s), joint and
    per segment. The tiny scene does not determine the specular weights (std up to 60, measured),
    so only the constraint and the known weight are asserted."""
    problem = _with_known(tiny_problem(tmp_path, kernels=("diffuse", "specular"), n_views=2, spp=16))
    left = 1.0 - problem.scene.segments[0].known["diffuse"]
    for cost in ("joint", "per_segment"):
        result = run_method("symbolic", problem, cost=cost)
        assert np.all(result.estimate[1] <= left + 1e-9), (cost, result.estimate[1])
        np.testing.assert_array_equal(result.estimate[0], [0.5, 0.4, 0.3])


def test_known_guess_leaves_room_for_the_free_kernels():
    """A segment of diffuse + specular with diffuse known at 0.8: a specular guess of 0.5 is
    scaled into the 0.2 the known weight leaves; a segment without known weights is untouched."""
    from types import SimpleNamespace

    from framework.scene.model import Parameter
    segs = (SimpleNamespace(known={"diffuse": np.array([0.8])}), SimpleNamespace(known=None))
    scene = SimpleNamespace(channels=("Y",), segments=segs)
    params = [Parameter(0, 0, "panel", "diffuse"), Parameter(1, 0, "panel", "specular"),
              Parameter(2, 1, "wall", "diffuse")]
    x = known_guess(np.array([[0.5], [0.5], [0.5]]), params, scene)
    np.testing.assert_allclose(x, [[0.8], [0.2], [0.5]])


def test_report_shows_a_known_weight_as_known():
    """The run report's parameter table reads "known" in the Observable column of a known weight."""
    from reports.run import parameter_rows
    row = {"segment": "panel", "kernel": "diffuse", "estimate": [0.5], "reference": [0.5], "error": [0.0],
           "std": [0.0], "observable": True, "ill_determined": False}
    _, rows, _ = parameter_rows({"channels": ["Y"], "parameters": [dict(row, known=True), dict(row, segment="wall")]})
    assert [r[2] for r in rows] == ["known", "yes"]
