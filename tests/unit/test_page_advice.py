"""Numpy's huge-page advice is off while a build runs, and as it was afterwards."""

import threading

import numpy as np
import pytest

import qem_core
from qem_core import page_advice
from qem_core.page_advice import without_huge_page_advice

pytestmark = pytest.mark.skipif(page_advice._set_madvise_hugepage is None,
                                reason="this numpy has no huge-page advice switch")

CUBE_VERTICES = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
CUBE_FACES = np.array([
    [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
    [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],
])


def advice_now() -> bool:
    """Numpy's current setting (the switch only tells it by setting it)."""
    setting = page_advice._set_madvise_hugepage(False)
    page_advice._set_madvise_hugepage(setting)
    return bool(setting)


@pytest.fixture(params=[True, False], ids=["advice on", "advice off"])
def setting_before(request):
    saved = page_advice._set_madvise_hugepage(request.param)
    yield request.param
    page_advice._set_madvise_hugepage(saved)


def test_off_inside_and_restored_after(setting_before):
    with without_huge_page_advice():
        assert advice_now() is False
        with without_huge_page_advice():
            assert advice_now() is False
        assert advice_now() is False  # an inner block leaves it off for the outer one
    assert advice_now() is setting_before


def test_restored_when_the_block_raises(setting_before):
    with pytest.raises(RuntimeError), without_huge_page_advice():
        raise RuntimeError("cancelled")
    assert advice_now() is setting_before


@pytest.mark.parametrize("thread_leaves_first", [True, False],
                         ids=["first in, first out", "first in, last out"])
def test_overlapping_threads_restore_when_the_last_leaves(setting_before, thread_leaves_first):
    entered, release, left = threading.Event(), threading.Event(), threading.Event()

    def hold():
        with without_huge_page_advice():
            entered.set()
            release.wait(10)
        left.set()

    thread = threading.Thread(target=hold)
    thread.start()
    assert entered.wait(10)
    with without_huge_page_advice():
        if thread_leaves_first:
            release.set()
            assert left.wait(10)
            assert advice_now() is False  # this block is still open
    if not thread_leaves_first:
        assert advice_now() is False  # the thread's block is still open
        release.set()
    thread.join(10)
    assert advice_now() is setting_before


def test_build_runs_without_the_advice_and_restores_it(setting_before):
    seen = []
    qem_core.build(CUBE_VERTICES, CUBE_FACES, progress=lambda fraction: seen.append(advice_now()))
    assert seen and not any(seen)
    assert advice_now() is setting_before


def test_a_cancelled_build_restores_it(setting_before):
    def cancel(fraction):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        qem_core.build(CUBE_VERTICES, CUBE_FACES, progress=cancel)
    assert advice_now() is setting_before
