"""The polynomial pass in tiles (methods/symbolic/system/polynomial_pass.py): a view's coefficients kept
as row blocks, on disk when the run has a cache, and every consumer reading them block by block."""
import numpy as np
import pytest

from factory import tiny_problem
from framework.cache import Cache
from framework.executor import SerialExecutor
from methods.symbolic.system.basis import MonomialBasis
from methods.symbolic.system.coefficients import TiledCoefficients, predicted
from methods.symbolic.system.pass_cache import TileLoader
from methods.symbolic.system.polynomial_pass import polynomial_pass, render_view_task, tile_pixels_for, view_task
from methods.symbolic.uncertainty.sandwich_meat import score_meat

#: 16 spp, N_max 3, 2 tail bounces, RGB: 4.5 KiB of event buffers a pixel, so 0.3 MiB gives tiles
#: of 68 pixels (4 tiles on the 16 x 16 views)
TINY_MEMORY_MB = 0.3


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    return tiny_problem(tmp_path_factory.mktemp("tiles"), n_views=2, spp=16)


def _pass(problem, cache, executor=None):
    x0 = np.full((len(problem.parameters), 3), 0.5)
    return polynomial_pass(problem, problem.parameters, x0, 3, spp=16, seed=0, prob_floor=0.1,
                           memory_mb=TINY_MEMORY_MB, cache=cache, tail_bounces=2, executor=executor)


def _everything(problem, passed):
    """The pass's system, images and sandwich meat at a fixed ρ: what the solve and the report use."""
    system = passed.take_system()
    basis = MonomialBasis(len(problem.parameters), 3, passed.codes)
    rho = np.random.default_rng(1).uniform(0.1, 0.4, (len(problem.parameters), 3))
    mu = np.stack([basis.evaluate(rho[:, c]) for c in range(3)])
    images = [predicted(passed.coefficients(c.name), mu, passed.codes) for c in problem.cameras]
    views = [(passed.coefficients(c.name), problem.observed[c.name], None) for c in problem.cameras]
    meat = score_meat(basis, rho, views, np.arange(basis.size), passed.codes)
    return system, images, meat


def _assert_same(a, b):
    (sa, ia, ma), (sb, ib, mb) = a, b
    np.testing.assert_array_equal(sa.codes, sb.codes)
    for ga, gb in zip(sa.G, sb.G):
        assert (ga != gb).nnz == 0
    np.testing.assert_array_equal(sa.b, sb.b)
    for x, y in zip(ia, ib):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(ma, mb)


def test_tiles_cover_the_view_in_order(problem):
    """Four tiles of 68, 68, 68 and 52 pixels; their rows add up to the view's pixels."""
    passed = _pass(problem, Cache(None))
    coeffs = passed.coefficients(problem.cameras[0].name)
    assert isinstance(coeffs, TiledCoefficients)
    blocks = list(coeffs.blocks())
    assert [s for s, _ in blocks] == [0, 68, 136, 204]
    assert [b.n_rows for _, b in blocks] == [68, 68, 68, 52]
    assert coeffs.n_rows == 256


def test_stored_tiles_give_the_same_bits(problem, tmp_path):
    """With a cache the worker stores each tile and the pass keeps none in memory; the system,
    the images and the sandwich meat equal the in-memory pass's bit for bit, and so do a second
    run's, which reads every view from the cache (its Gram systems rebuilt from the tiles)."""
    memory = _everything(problem, _pass(problem, Cache(None)))
    first = _pass(problem, Cache(tmp_path))
    assert first.from_cache == []
    assert all(callable(b) for name in first.views for b in first.coefficients(name)._blocks)
    _assert_same(memory, _everything(problem, first))
    second = _pass(problem, Cache(tmp_path))
    assert second.from_cache == [c.name for c in problem.cameras]
    _assert_same(memory, _everything(problem, second))


def test_workers_elsewhere_send_their_tiles_to_be_stored_here(problem, tmp_path):
    """Workers of a remote scheduler (``tasks_here`` 0: they cannot reach the cache folder) return
    their tiles, which the driver stores: same files and bits as workers on this machine."""
    class Elsewhere(SerialExecutor):
        tasks_here = 0

    memory = _everything(problem, _pass(problem, Cache(None)))
    remote = _pass(problem, Cache(tmp_path), Elsewhere())
    assert len(list((tmp_path / "polynomial_tile").glob("*.npz"))) == 8
    _assert_same(memory, _everything(problem, remote))
    _assert_same(memory, _everything(problem, _pass(problem, Cache(tmp_path))))


def test_a_task_storing_its_tiles_returns_their_loaders(problem, tmp_path):
    """``render_view_task`` with a cache folder (what the bench's megapixel pass and a Dask worker
    on this machine run) returns loaders reading each stored tile back: the same blocks."""
    x0 = np.full((len(problem.parameters), 3), 0.5)
    tile = tile_pixels_for(TINY_MEMORY_MB, 16, 3, 3, 2)
    task = lambda **kw: view_task(problem, problem.parameters, x0, 3, 0, spp=16, seed=0, prob_floor=0.1,
                                  tile_pixels=tile, cross_gram=True, tail_bounces=2, **kw)
    variant = problem.settings.variant
    _, held = render_view_task(task(), variant=variant)
    _, stored = render_view_task(task(cache_dir=tmp_path, key={"view": "v", "test": 1}), variant=variant)
    assert all(isinstance(b, TileLoader) for b in stored._blocks)
    for (s0, a), (s1, b) in zip(held.blocks(), stored.blocks()):
        assert s0 == s1
        np.testing.assert_array_equal(a.codes, b.codes)
        for x, y in zip(a.a + a.b, b.a + b.b):
            assert (x != y).nnz == 0


def test_a_missing_tile_renders_the_view_again(problem, tmp_path):
    """A view whose index is cached but one of whose tiles is gone is rendered again (same bits)."""
    memory = _everything(problem, _pass(problem, Cache(tmp_path)))
    tiles = sorted((tmp_path / "polynomial_tile").glob("*.npz"))
    assert len(tiles) == 8                          # 2 views x 4 tiles
    tiles[3].unlink()
    again = _pass(problem, Cache(tmp_path))
    assert len(again.from_cache) == 1
    _assert_same(memory, _everything(problem, again))


def test_a_pass_stored_by_other_code_is_rendered_again(problem, tmp_path, monkeypatch):
    """The pass's key holds the digest of its code (``PASS_CODE``): after an edit of it (here its
    digest replaced) the stored tiles are not read back."""
    import methods.symbolic.system.pass_cache as pass_cache
    _pass(problem, Cache(tmp_path))
    assert len(_pass(problem, Cache(tmp_path)).from_cache) == 2
    monkeypatch.setattr(pass_cache, "code_version", lambda *modules: "edited")
    assert _pass(problem, Cache(tmp_path)).from_cache == []


def test_the_system_is_taken_once(problem):
    passed = _pass(problem, Cache(None))
    passed.take_system()
    with pytest.raises(RuntimeError, match="already taken"):
        passed.take_system()


def test_only_resampled_photographs_are_rendered_over_a_footprint(problem):
    """The pass integrates over the interpolation's footprint exactly where the loader resampled
    the photographs: a distorted camera with photographs (the scene's ``resampling`` kernel),
    not a pinhole one, nor observations the framework rendered itself; the cache key tells the
    two renders apart."""
    from dataclasses import replace
    from types import SimpleNamespace
    from factory import distorted
    from methods.symbolic.system.pass_cache import footprint_kernel, view_key
    cam = problem.cameras[0]
    lens = distorted(cam, "OPENCV")
    photographed = SimpleNamespace(scene=replace(problem.scene, images={}, photometry=replace(
        problem.scene.photometry, resampling="cubic")))
    rendered = SimpleNamespace(scene=replace(problem.scene, images=None))
    assert footprint_kernel(photographed, lens) == "cubic"
    assert footprint_kernel(photographed, cam) is None
    assert footprint_kernel(rendered, lens) is None
    key = lambda footprint: view_key(problem, lens, problem.parameters, np.zeros((1, 3)), 4, 0, 0.1, 3,  # noqa: E731
                                     view=0, cross_gram=True, tail_bounces=0, footprint=footprint)
    assert key("cubic") != key(None) and key("cubic") != key("bilinear")


@pytest.mark.parametrize("clustered", [False, True])
def test_the_meat_scored_in_row_chunks_equals_the_whole_blocks(problem, monkeypatch, clustered):
    """score_meat scores a block's rows in chunks of about SCORE_CHUNK_NNZ coefficients (its
    temporaries bounded whatever the tile): with chunks of a few pixels the meat, pixel or
    cluster sums, equals the one scored block by block to 1e-12 (relative; only the order of the
    sums differs)."""
    import methods.symbolic.uncertainty.sandwich_meat as U
    passed = _pass(problem, Cache(None))
    basis = MonomialBasis(len(problem.parameters), 3, passed.codes)
    rho = np.random.default_rng(1).uniform(0.1, 0.4, (len(problem.parameters), 3))
    views = [(passed.coefficients(c.name), problem.observed[c.name], None) for c in problem.cameras]
    clusters = [np.arange(256) // 16 for _ in problem.cameras] if clustered else None
    whole = score_meat(basis, rho, views, np.arange(basis.size), passed.codes, clusters=clusters)
    block = next(passed.coefficients(problem.cameras[0].name).blocks())[1]
    monkeypatch.setattr(U, "SCORE_CHUNK_NNZ", max(1, (block.a[0].nnz + block.b[0].nnz) // 7))
    assert len(U._row_chunks(block)) >= 6
    chunked = score_meat(basis, rho, views, np.arange(basis.size), passed.codes, clusters=clusters)
    np.testing.assert_allclose(chunked, whole, rtol=1e-12, atol=1e-12 * np.abs(whole).max())


def test_a_stored_tile_reads_its_quarters_only_to_be_halved(tmp_path):
    """A plain read of a stored tile leaves its quarters (``a1``, ``b1``) unread; the halves of the
    cached view read them, and equal the halves of the tile as it was stored, bit for bit."""
    import scipy.sparse as sp

    from methods.symbolic.system.coefficients import ViewCoefficients
    from methods.symbolic.system.pass_cache import store_tile
    rng = np.random.default_rng(4)
    mats = [[sp.random(6, 5, density=0.5, format="csr", random_state=rng) for _ in range(2)] for _ in range(4)]
    block = ViewCoefficients(mats[0], mats[1], 0.5, np.arange(5), mats[2], mats[3])
    loader = store_tile(Cache(tmp_path), {"view": "v", "tile": 0}, 0, block, 2)
    plain = loader()
    assert plain.a1 is None and plain.b1 is None
    assert all(np.array_equal(m.toarray(), n.toarray()) for m, n in zip(plain.a, block.a))
    for j in (0, 1):
        (_, half), = TiledCoefficients([0], [loader], 6).halved(j).blocks()
        expected = block.halved(j)
        for got, want in ((half.a, expected.a), (half.b, expected.b)):
            assert all(np.array_equal(m.toarray(), n.toarray()) for m, n in zip(got, want))
