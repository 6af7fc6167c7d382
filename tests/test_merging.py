"""Tests of awr_denoise.merging: Chan's update, block by block, against the formulas written out."""

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from awr_denoise import fused, merging
from awr_denoise.merging import merge_moments

BACKENDS = [pytest.param(name, marks=pytest.mark.skipif(name not in fused.available(),
                                                        reason="numba is not installed (extra 'fast')"))
            for name in fused.BACKENDS]


def _chan(ca, ma, va, cb, mb, vb):
    """The update on whole arrays at once, in the same order of operations."""
    na, nb = ca[..., None].astype(np.float64), cb[..., None].astype(np.float64)
    n = na + nb
    safe = np.maximum(n, 1.0)
    delta = mb - ma
    mean = delta * (nb / safe) + ma
    m2 = va * np.maximum(ca - 1, 0)[..., None] + vb * np.maximum(cb - 1, 0)[..., None] + delta * delta * (na * nb / safe)
    variance = m2 / np.maximum(n - 1.0, 1.0)
    mean = np.where(na == 0, mb, np.where(nb == 0, ma, mean))
    variance = np.where(na == 0, vb, np.where(nb == 0, va, variance))
    return mean, variance


@pytest.mark.parametrize("block_bytes", [1, 8 * 29 * 3 * 4, merging.BLOCK_BYTES])
def test_blocks_give_the_formulas_bits(rng, monkeypatch, block_bytes):
    """One row per block, four rows per block (the last block short: 23 rows), or one block: the same bits."""
    monkeypatch.setattr(merging, "BLOCK_BYTES", block_bytes)
    shape = (23, 29)
    sides = [(rng.integers(0, 5, shape), rng.lognormal(0, 3, shape + (3,)), rng.lognormal(0, 3, shape + (3,)))
             for _ in range(2)]
    mean, variance = merge_moments(*sides[0], *sides[1])
    want_mean, want_variance = _chan(*sides[0], *sides[1])
    assert_array_equal(mean.view(np.int64), want_mean.view(np.int64))
    assert_array_equal(variance.view(np.int64), want_variance.view(np.int64))


def _sides(rng, shape, channels=3):
    """Two sides' statistics over many magnitudes and both signs, with pixels of 0, 1 and more samples."""
    out = []
    for _ in range(2):
        count = rng.integers(0, 6, shape)
        mean = rng.lognormal(0, 20, shape + (channels,)) * rng.choice([-1.0, 1.0], shape + (channels,))
        out += [count, mean, rng.lognormal(0, 20, shape + (channels,)) * (count[..., None] > 1)]
    return out


def test_the_loop_written_out_gives_the_blocks_bits(rng):
    """The compiled kernel's source, run as Python: each pixel and channel the floats of the whole-array passes."""
    args = _sides(rng, (6, 5), channels=2)
    mean, variance = np.empty((6, 5, 2)), np.empty((6, 5, 2))
    merging._merge_loop(*args, mean, variance)
    want_mean, want_variance = merge_moments(*args)
    assert_array_equal(mean.view(np.int64), want_mean.view(np.int64))
    assert_array_equal(variance.view(np.int64), want_variance.view(np.int64))


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("shape", [(1, 1), (23, 29), (64, 7)])
def test_each_backend_gives_the_references_bits_on_one_thread_and_two(rng, backend, shape):
    """The compiled merge (``AWR_DENOISE_KERNELS=numba``) against the numpy blocks, bit for bit."""
    from concurrent.futures import ThreadPoolExecutor

    args = _sides(rng, shape)
    with fused.using("numpy"):
        want = merge_moments(*args)
    with fused.using(backend), ThreadPoolExecutor(2) as pool:
        for executor in (None, pool):
            for got, expected in zip(merge_moments(*args, executor=executor), want):
                assert_array_equal(got.view(np.int64), expected.view(np.int64))


def test_equals_the_statistics_of_all_samples(rng):
    samples = rng.normal(3.0, 2.0, (2, 4, 9))  # (H, W, samples)
    a, b = samples[..., :4], samples[..., 4:]
    stats = lambda s: (np.full((2, 4), s.shape[-1]), s.mean(-1)[..., None], s.var(-1, ddof=1)[..., None])  # noqa: E731
    mean, variance = merge_moments(*stats(a), *stats(b))
    assert_allclose(mean[..., 0], samples.mean(-1), rtol=1e-14)
    assert_allclose(variance[..., 0], samples.var(-1, ddof=1), rtol=1e-12)


def test_an_empty_side_gives_the_other_side_bit_for_bit(rng):
    shape = (5, 7)
    count = rng.integers(2, 50, shape)
    mean, variance = rng.random(shape + (2,)), rng.random(shape + (2,))
    zeros = np.zeros(shape + (2,))
    for args in ((np.zeros(shape, np.int64), zeros, zeros, count, mean, variance),
                 (count, mean, variance, np.zeros(shape, np.int64), zeros, zeros)):
        got_mean, got_variance = merge_moments(*args)
        assert_array_equal(got_mean, mean)
        assert_array_equal(got_variance, variance)


@pytest.mark.parametrize("shape", [(1, 5), (3, 4), (37, 11), (200, 64)])
def test_merging_on_two_threads_gives_the_same_bits(shape):
    """The halves of the rows on an executor's threads: the serial merge's bits, at sizes with one
    block, a half of zero blocks (serial) and halves that split blocks."""
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(9)
    h, w = shape
    args = []
    for _ in range(2):
        count = rng.integers(0, 4, shape)
        args += [count, rng.random((h, w, 3)), rng.random((h, w, 3)) * (count[..., None] > 1)]
    serial = merging.merge_moments(*args)
    with ThreadPoolExecutor(2) as pool:
        for block_bytes in (merging.BLOCK_BYTES, 3 * w * 3 * 8):  # one block, or blocks of three rows
            with pytest.MonkeyPatch.context() as patch:
                patch.setattr(merging, "BLOCK_BYTES", block_bytes)
                threaded = merging.merge_moments(*args, executor=pool)
            for a, b in zip(serial, threaded):
                np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("big", [1e200, 1.5e308])
@pytest.mark.parametrize("threads", [False, True])
def test_statistics_past_float64_once_merged_are_refused_by_name_without_warnings(big, threads, backend,
                                                                                   monkeypatch):
    """Two buffers of samples +big and -big: the merged variance (or the difference of the means)
    passes float64. The merge leaked numpy's overflow warnings and was refused as "variance: 1
    pixel(s) hold NaN or Inf", an array the caller never passed (a red-team pass)."""
    import warnings
    from concurrent.futures import ThreadPoolExecutor

    from awr_denoise import SampleBuffer

    monkeypatch.setattr(merging, "BLOCK_BYTES", 16)  # a block a row: the last rows on the second thread
    at = np.array([7, 7])  # row 3 of a (4, 2) image
    a = SampleBuffer.from_samples(at, np.array([[big], [big]]), (4, 2))
    b = SampleBuffer.from_samples(at, np.array([[-big], [-big]]), (4, 2))
    with warnings.catch_warnings(), ThreadPoolExecutor(2) as pool, fused.using(backend):
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=r"^other: merged, the mean or variance of 1 pixel\(s\) is beyond float64"):
            a.merge(b, executor=pool if threads else None)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("threads", [False, True])
def test_a_merge_whose_sums_pass_float64_but_not_its_result_is_the_statistics_of_all_samples(threads, backend):
    """Samples of +-2**510 (and two singles of +-0.75e154): their M2 and the squared difference of the halves'
    means pass float64, the variance does not. from_samples gives it; the merge refused it, so a pixel traced in
    parts, or told in two rounds, was refused where one part was not (a red-team pass)."""
    import warnings
    from concurrent.futures import ThreadPoolExecutor

    from awr_denoise import SampleBuffer

    signs = np.where(np.arange(4096) % 3 == 0, 1.0, -1.0)
    cases = [(np.zeros(4096, np.int64) + 5, np.ldexp(signs, 510)[:, None], 2048),
             (np.array([5, 5]), np.array([[0.75e154], [-0.75e154]]), 1)]
    for at, samples, half in cases:
        whole = SampleBuffer.from_samples(at, samples, (2, 3))
        a = SampleBuffer.from_samples(at[:half], samples[:half], (2, 3))
        b = SampleBuffer.from_samples(at[half:], samples[half:], (2, 3))
        with warnings.catch_warnings(), ThreadPoolExecutor(2) as pool, fused.using(backend):
            warnings.simplefilter("error")
            merged = a.merge(b, executor=pool if threads else None)
        assert 1e306 < whole.variance[1, 2, 0] < 1.8e308
        np.testing.assert_allclose(merged.variance, whole.variance, rtol=1e-12)
        np.testing.assert_allclose(merged.mean, whole.mean, rtol=1e-12, atol=1e-12 * np.abs(samples).max())


def test_a_buffer_merged_with_itself_is_refused():
    """``b.merge(b)`` doubled the counts of the same samples without a word (the command line refuses
    its equivalent; a red-team pass). A buffer with equal but separate statistics still merges."""
    import copy

    from awr_denoise import SampleBuffer

    b = SampleBuffer.from_samples(np.array([0, 0, 1]), np.array([[1.0], [2.0], [3.0]]), (1, 2))
    with pytest.raises(ValueError, match=r"^other: the same statistics as the buffer merged into"):
        b.merge(b)
    assert b.merge(copy.deepcopy(b)).total_samples == 6
