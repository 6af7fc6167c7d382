"""The water-filling: its level where pixels are capped, and its rounding against a full partition.

The contract of :func:`~awr_denoise.allocate` itself (budget, caps, refusals) is tested in
test_sampling.py beside the samplers that call it.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from awr_denoise import allocate
from awr_denoise.allocation import _SELECT_DIRECT, _smallest, allocate_mixed


def _reference(key: np.ndarray, count: int) -> np.ndarray:
    """The selection as it was made before the bracketed search: one partition of every key."""
    mask = np.zeros(key.size, bool)
    mask[np.argpartition(key, count - 1)[:count]] = True
    return mask


def _keys(kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """Keys like the rounding's: minus (remainder + tiny jitter), +Inf where a pixel has no room."""
    if kind == "uniform":
        frac = rng.random(n)
    elif kind == "equal":  # a flat density: every remainder the same, only the jitter differs
        frac = np.full(n, 0.375)
    elif kind == "few values":
        frac = rng.integers(0, 4, n) / 4.0
    elif kind == "periodic":  # a pattern that repeats every 16 pixels: a strided sample would alias
        frac = np.tile(np.linspace(0.0, 0.9, 16), n // 16 + 1)[:n]
    else:  # sorted: the smallest keys all at one end of the image
        frac = np.sort(rng.random(n))
    key = -(frac + 1e-6 * rng.random(n))
    if kind == "removal":  # the rounding's other use: the smallest remainders lose a sample
        key = -key
        key[rng.random(n) < 0.2] = np.inf  # pixels with no sample to give
    if kind == "uniform":
        key[rng.random(n) < 0.3] = np.inf  # pixels at their cap
    return key


@pytest.mark.parametrize("kind", ["uniform", "equal", "few values", "periodic", "sorted", "removal"])
@pytest.mark.parametrize("share", [1e-5, 0.01, 0.37, 0.5, 0.69, 0.999])
def test_the_bracketed_selection_is_the_full_partitions(kind, share):
    rng = np.random.default_rng(7)
    n = 3 * _SELECT_DIRECT + 11  # above the size where the bracket is used
    key = _keys(kind, n, rng)
    count = max(1, min(int(share * np.count_nonzero(np.isfinite(key))), n - 1))
    got = _smallest(key, count)
    assert got.dtype == bool and int(got.sum()) == count
    np.testing.assert_array_equal(got, _reference(key, count))


def test_a_sample_that_misses_falls_back_to_the_full_partition(monkeypatch):
    """Places that all fall on the largest keys bracket the wrong values: the result is still exact."""
    from awr_denoise import allocation

    rng = np.random.default_rng(3)
    n = 2 * _SELECT_DIRECT
    key = -rng.random(n)
    order = np.argsort(key)
    monkeypatch.setattr(allocation, "_sample_places", lambda size: order[-(size // 16):])
    count = n // 2
    np.testing.assert_array_equal(_smallest(key, count), _reference(key, count))


def test_small_images_partition_directly():
    rng = np.random.default_rng(1)
    key = -rng.random(1000)
    np.testing.assert_array_equal(_smallest(key, 417), _reference(key, 417))


def test_allocation_above_the_bracket_size_is_the_full_partitions(monkeypatch):
    """Through allocate(), with caps and without: the counts of the full partition."""
    from awr_denoise import allocation

    rng = np.random.default_rng(11)
    shape = (300, 500)
    density = rng.random(shape) ** 3
    current = rng.integers(0, 3, shape)
    capacity = rng.integers(0, 6, shape)
    for budget, cap in ((int(0.6 * capacity.sum()), capacity), (12345, capacity), (10**8, None)):
        got = allocate(density, current, budget, capacity=cap, rng=np.random.default_rng(0))
        with monkeypatch.context() as patch:
            patch.setattr(allocation, "_smallest", _reference)
            expected = allocate(density, current, budget, capacity=cap, rng=np.random.default_rng(0))
        assert int(got.sum()) == budget and (cap is None or (got <= cap).all())
        np.testing.assert_array_equal(got, expected)


def test_the_counts_do_not_depend_on_the_densitys_scale():
    """Documented as "any scale": near 1e308 the water level's sum overflowed and the density was
    ignored (a uniform split and a warning; a red-team pass), and subnormal densities underflowed."""
    rng = np.random.default_rng(5)
    current = rng.integers(0, 3, size=(9, 11))
    density = rng.random((9, 11)) ** 3
    density[0, :3] = 0.0
    expected = allocate(density, current, 500, rng=np.random.default_rng(1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for scale in (2.0**-1060, 1e-300, 1e300, 1.7e308 / density.max()):
            got = allocate(density * scale, current, 500, rng=np.random.default_rng(1))
            assert_array_equal(got, expected, err_msg=f"scale {scale:g}")
            capped = allocate(density * scale, current, 300, capacity=np.full((9, 11), 4),
                              rng=np.random.default_rng(1))
            assert_array_equal(capped, allocate(density, current, 300, capacity=np.full((9, 11), 4),
                                                rng=np.random.default_rng(1)))


@pytest.mark.parametrize("closed", [1.5e308, 1e200, 1.0])
def test_a_closed_pixel_of_any_density_leaves_the_budget_to_the_open_ones(closed):
    """A pixel at its cap takes nothing whatever its density: one 2**1024 times denser than the open ones
    overflowed their scaling, and a budget that fits was refused (a red-team pass)."""
    density = np.array([[closed, 2e-200, 1e-200]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = allocate(density, np.zeros((1, 3), np.int64), 3, capacity=np.array([[0, 5, 5]]))
    assert_array_equal(got, [[0, 2, 1]])


@pytest.mark.parametrize("fraction", [1.0, 0.5, 0.9999999])
def test_the_uniform_share_of_a_budget_past_2_53_is_exact(fraction):
    """The uniform share in exact arithmetic: 1.0 * (2**53 + 3) rounded in float64 to 2**53 + 4, one more than
    the budget ("budget: must be >= 0, got -1")."""
    budget = 2**53 + 3
    got = allocate_mixed(np.ones((1, 2)), np.zeros((1, 2), np.int64), budget, fraction)
    assert int(got.sum()) == budget and abs(int(got[0, 0]) - int(got[0, 1])) <= 1


@pytest.mark.parametrize(("density", "current", "capacity", "budget", "want"), [
    # The dense pixels capped and the others holding samples already: doubling the water level once added
    # nothing, was taken for saturation, and the rest of the budget went out evenly (25 each; a red-team pass).
    ([1.0, 1.0, 1e-3, 2e-3, 3e-3, 4e-3], [0, 0, 5, 5, 5, 5], [1, 1, 1000, 1000, 1000, 1000], 102,
     [1, 1, 7, 19, 31, 43]),
    # Pixels of no density are filled level: the one already at 50 takes none (it took 20).
    ([1.0, 0.0, 0.0], [0, 2, 50], [1, 100, 100], 41, [1, 40, 0]),
])
def test_capped_pixels_leave_the_rest_to_the_water_level(density, current, capacity, budget, want):
    got = allocate(np.array([density]), np.array([current]), budget, capacity=np.array([capacity]))
    assert_array_equal(got, [want])
    # The pixels past the first capped ones get what they get alone, with what the capped ones left.
    rest = slice(capacity.count(1), None)
    alone = allocate(np.array([density])[:, rest], np.array([current])[:, rest], budget - capacity.count(1),
                     capacity=np.array([capacity])[:, rest])
    assert_array_equal(got[:, rest], alone)
