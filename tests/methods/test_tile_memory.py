"""The device memory of the polynomial pass's tiles (methods/symbolic/trace/tile_memory.py): the
model against what Dr.Jit's allocator holds, measured by its watermark (the same allocator serves
the ``cuda_*`` variants' device memory)."""
import numpy as np
import pytest

from factory import tiny_problem
from framework.render.jit_timing import allocation_peak
from methods.symbolic.system.polynomial_pass import render_view_task, tile_bytes, tile_pixels_for, view_task
from methods.symbolic.trace.tile_memory import allocated, tile_device_bytes

MiB = 2 ** 20


def test_allocated_is_the_next_power_of_two():
    """By hand: drjit-core's ``jit_malloc`` rounds every request up to a power of two."""
    assert [allocated(b) for b in (0, 1, 3, 4, 5, 4096, 4097)] == [0, 1, 4, 4, 8, 4096, 8192]
    assert allocated(3 * 2 ** 30) == 2 ** 32


def test_tile_device_bytes_by_hand():
    """64 pixels x 16 spp x 4 slots: 4-byte arrays of 16 KiB each. A key and 3 values, the
    compacted slots, their columns and the sums' work arrays (twice half of one): 7 x 16 KiB; the
    lanes' offsets P(4 KiB), the pixels' event counts 2 P(512 B), the key table over 13³ keys
    2 P(8788 B)."""
    expected = 7 * 16384 + 4096 + 2 * 512 + 2 * 16384
    assert tile_device_bytes(64, 16, 4, 3, 13 ** 3) == expected
    # a key range without a table: no table nor columns, the host path's gathered arrays (2 x 16 KiB)
    assert tile_device_bytes(64, 16, 4, 3, 2 ** 40) == 5 * 16384 + 2 * 16384 + 4096 + 2 * 512


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    return tiny_problem(tmp_path_factory.mktemp("tile_memory"), spp=16)


#: 0.3 MiB: tiles of 68 pixels at 16 spp, N_max 3, T 2 (the 16 x 16 view in 4 tiles, the last of 52)
MEMORY_MB = 0.3


@pytest.mark.parametrize("case", ["halves", "quarters", "one block", "host sums"])
def test_a_views_device_peak_stays_within_the_model_and_memory_mb(problem, case, monkeypatch):
    """A whole view's pass (its tiles one after the other, the last one smaller) holds at most
    the modelled bytes of one tile, which fit in ``method.memory_mb``; and at least half of them
    (the model is not loose). Measured on the LLVM backend, 2026-12-05: 183-229 KiB against a model of
    234 KiB, in a budget of 307 KiB."""
    import methods.symbolic.trace.pixel_sums as PS
    import methods.symbolic.trace.tile_memory as TM
    if case == "host sums":               # a key range without a table: the events summed on the host
        monkeypatch.setattr(PS, "TABLE_KEYS", 0)
        monkeypatch.setattr(TM, "TABLE_KEYS", 0)
    D = len(problem.parameters)
    tile = tile_pixels_for(MEMORY_MB, 16, 3, 3, 2, n_params=D)
    x0 = np.full((D, 3), 0.5)
    task = view_task(problem, problem.parameters, x0, 3, 0, spp=16, seed=0, prob_floor=0.1, tile_pixels=tile,
                     cross_gram=case != "one block", tail_bounces=2, quarters=case == "quarters")
    variant = problem.settings.variant
    render_view_task(task, variant=variant)                  # the scene built, the kernels compiled
    peak, (_, coeffs) = allocation_peak(lambda: render_view_task(task, variant=variant))
    model = tile_bytes(tile, 16, 3, 3, 2, n_params=D)
    assert len(coeffs.starts) == 4 and coeffs.n_rows - coeffs.starts[-1] < tile
    assert 0.5 * model <= peak <= model <= MEMORY_MB * MiB


def test_tiles_shrink_until_the_model_fits():
    """By hand, 12.1 MiB at 16 spp, 6 slots (N_max 3, T 2), 3 channels, 6 weights (7³ path keys):
    a third of it is 2753 pixels (1536 event bytes each), whose 4-byte arrays of 1,057,152 bytes
    are allocated as 2 MiB: 7 x 2 MiB + the lanes' offsets (256 KiB) + the pixels' counts
    (2 x 32 KiB) + the key table (2 x 2 KiB) = 14.32 MiB, too much. The next power of two down
    holds 2730 pixels (arrays of 1,048,320 bytes, allocated as 1 MiB): 7.32 MiB."""
    tile = tile_pixels_for(12.1, 16, 3, 3, 2, n_params=6)
    assert tile == 2730
    assert tile_bytes(tile, 16, 3, 3, 2, n_params=6) == 7 * MiB + 2 ** 18 + 2 * 2 ** 15 + 2 * 2 ** 11
    assert tile_bytes(2753, 16, 3, 3, 2, n_params=6) == 14 * MiB + 2 ** 18 + 2 * 2 ** 15 + 2 * 2 ** 11
