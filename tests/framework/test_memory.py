"""framework.memory: freed heap memory handed back to the operating system, or kept for reuse."""
import numpy as np
import psutil
import pytest

from framework.memory import release_freed_memory, reused_memory


@pytest.mark.parametrize("after_block", [False, True])
def test_release_returns_the_holes_of_a_fragmented_heap(after_block):
    """Every other 1 MiB array freed (held in the heap, not mmapped: a freed 30 MiB array first
    raises glibc's adaptive mmap threshold to 30 MiB, or a :func:`reused_memory` block left it at
    32 MiB) stays resident until the trim, which returns most of the 150 MiB; measured on this
    machine: 150 MiB returned. Asserted > 100 MiB."""
    if not release_freed_memory():
        pytest.skip("not glibc: nothing to release")
    if after_block:
        with reused_memory():
            pass
    big = np.ones(30 * 2**20 // 8)
    del big                                     # threshold now 30 MiB: the 1 MiB arrays use the heap
    arrays = [np.ones(2**20 // 8) for _ in range(300)]
    del arrays[::2]                             # 150 holes of 1 MiB below live arrays
    before = psutil.Process().memory_info().rss
    assert release_freed_memory()
    after = psutil.Process().memory_info().rss
    assert before - after > 100 * 2**20, (before - after) / 2**20
    assert sum(a[0] for a in arrays) == 150     # the live ones are untouched


def _rss() -> int:
    return psutil.Process().memory_info().rss


def test_reused_memory_keeps_freed_arrays_until_the_block_ends():
    """A freed 64 MiB array (above glibc's largest mmap threshold, 32 MiB, so unmapped at once
    outside a block) stays resident inside :func:`reused_memory` and is returned at its end.
    The array is written whole (64 MiB resident); asserted: more than 48 MiB kept, then more
    than 48 MiB returned, and less than 16 MiB kept without the block."""
    if not release_freed_memory():
        pytest.skip("not glibc: nothing to keep")
    n = 64 * 2**20 // 8
    big = np.ones(n)
    before = _rss()
    del big
    assert before - _rss() > 48 * 2**20        # outside a block: unmapped when freed
    with reused_memory():
        big = np.ones(n)
        before = _rss()
        del big
        kept = _rss()
        assert before - kept < 16 * 2**20      # kept for the next array
        again = np.ones(n)                     # served from the kept memory
        assert _rss() - kept < 16 * 2**20
        del again
    assert kept - _rss() > 48 * 2**20          # returned at the block's end


def test_reused_memory_nested_blocks_act_as_the_outermost():
    """The inner block's end neither restores the defaults nor trims: a 64 MiB array freed
    after it stays resident until the outer block ends (asserted as above)."""
    if not release_freed_memory():
        pytest.skip("not glibc: nothing to keep")
    n = 64 * 2**20 // 8
    with reused_memory():
        with reused_memory():
            pass
        big = np.ones(n)
        before = _rss()
        del big
        assert release_freed_memory()          # waits for the block's end
        kept = _rss()
        assert before - kept < 16 * 2**20
    assert kept - _rss() > 48 * 2**20


def test_reused_memory_restores_after_an_error():
    """An exception inside the block ends it: a 64 MiB array freed afterwards is unmapped."""
    if not release_freed_memory():
        pytest.skip("not glibc: nothing to keep")
    with pytest.raises(RuntimeError, match="inside"):
        with reused_memory():
            raise RuntimeError("inside")
    big = np.ones(64 * 2**20 // 8)
    before = _rss()
    del big
    assert before - _rss() > 48 * 2**20
