"""awr_denoise.rare_paths: regions lit through rare paths found, and the samplers' samples spread evenly there."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from awr_denoise import AdaptiveSampler, SampleBuffer, VarianceSampler, rare_paths
from awr_denoise.rare_paths import BACKDROP, RARE_PATHS, even_rare_paths, rare_path_mask
from awr_denoise.synthetic import SyntheticRenderer, SyntheticScene, make_scene


def _hits(p, shape=(64, 64), n=4, value=None, seed=0):
    """(count, mean, variance) of ``n`` samples a pixel that are ``value`` (default 1 / p) with chance p, else 0."""
    value = 1.0 / p if value is None else value
    hits = np.random.default_rng(seed).binomial(n, p, size=shape).astype(float)
    mean = hits * value / n
    variance = (hits * (value - mean) ** 2 + (n - hits) * mean**2) / (n - 1)
    return np.full(shape, n), mean, variance


def _sparks(p=0.004, spike=100.0, shape=(96, 96), n=4, base=0.5, seed=0):
    """(count, mean, variance) of ``n`` samples a pixel of a lit base: ``spike`` times ``base`` with chance p (a
    firefly), else ``base`` with a sd of 10%."""
    rng = np.random.default_rng(seed)
    hits = rng.binomial(n, p, size=shape).astype(float)
    steady = base * (1.0 + 0.1 * rng.standard_normal((n,) + shape))  # the steady samples, the first n - hits
    taken = np.arange(n)[:, None, None] < (n - hits)
    samples = np.where(taken, steady, spike * base)
    return np.full(shape, n), samples.mean(axis=0), samples.var(axis=0, ddof=1)


def _buffer(count, mean, variance):
    return SampleBuffer.from_moments(count, np.repeat(mean[..., None], 3, -1), np.repeat(variance[..., None], 3, -1))


def test_a_region_of_rare_hits_is_found_and_steady_noise_beside_it_is_not():
    count, mean, variance = _hits(1 / 40)
    mean[:, 32:], variance[:, 32:] = 1.0, 0.5  # steady noise: every sample lit
    mask = rare_path_mask(_buffer(count, mean, variance))
    assert mask[:, :24].mean() > 0.9 and not mask[:, 40:].any()


@pytest.mark.parametrize("p", [0.1, 0.3, 0.6])
def test_hits_that_are_not_rare_are_not_a_rare_path_region(p):
    """A hit chance of 1 in 10 (a CV2 of 9, below RARE_CV2's 16) and more: its pixels' statistics rank them."""
    assert not rare_path_mask(_buffer(*_hits(p, n=8))).any()


def test_a_small_light_seen_directly_is_not_a_rare_path_region():
    """A light 2 pixels across, 1000 times its dim noisy surroundings: its pixels hit often."""
    rng = np.random.default_rng(1)
    mean = rng.uniform(0.05, 0.15, (64, 64))
    variance = (0.5 * mean) ** 2
    mean[30:32, 30:32], variance[30:32, 30:32] = 100.0, 400.0
    mean[29, 30:32] = mean[32, 30:32] = 50.0  # its rim: half its samples hit it
    variance[29, 30:32] = variance[32, 30:32] = 50.0**2 * 4 / 3
    assert not rare_path_mask(_buffer(np.full((64, 64), 4), mean, variance)).any()


def test_a_black_backdrop_beside_a_thin_wire_is_not_read_as_rare_hits():
    """A wire one pixel wide against black, one sample in eight hitting it: its pixels hold about one hit each and
    its window's pooled CV2 is high, but the zeros around it fill squares of BACKDROP pixels, a backdrop, not a
    region's misses (without the rule about a third of the frame is taken for rare paths)."""
    count = np.full((64, 64), 8)
    mean, variance = np.zeros((64, 64)), np.zeros((64, 64))
    mean[:, 32], variance[:, 32] = 0.5 / 8, 0.5**2 / 8
    assert BACKDROP <= 32
    assert not rare_path_mask(_buffer(count, mean, variance)).any()


def test_a_steady_surface_with_bright_sparkles_is_not_rare_paths():
    """Every sample lights a dim surface (mean 0.001) and 5% of its pixels are sparkles 1000 times as bright: the
    pooled CV2 is above RARE_CV2, but no pixel holds its mean in one sample, so the share test (RARE_SHARE)
    rejects it (without it, most of the frame is taken for rare paths)."""
    rng = np.random.default_rng(0)
    mean = np.full((64, 64), 0.001)
    mean[rng.random((64, 64)) < 0.05] = 1.0
    assert not rare_path_mask(_buffer(np.full((64, 64), 8), mean, mean**2)).any()


@pytest.mark.parametrize("n", [2, 4, 8, 32])
@pytest.mark.parametrize("seed", [0, 1])
def test_fireflies_on_a_lit_base_are_a_rare_path_region(n, seed):
    """One sample in 250 is 100 times its lit base, which holds the rest of the light: most pixels have seen none
    and look steady, so the first tests miss it, and the tests of rare hits on a lit base find it."""
    buffer = _buffer(*_sparks(n=n, seed=seed))
    assert rare_path_mask(buffer).mean() > 0.9
    assert rare_path_mask(buffer, fireflies=False).mean() < 0.1
    density = np.random.default_rng(seed).uniform(0.0, 2.0, (96, 96))
    assert (even_rare_paths(density, buffer) != density).mean() > 0.9
    np.testing.assert_array_equal(even_rare_paths(density, buffer, "zeros"), density)  # the first kind only


def test_the_rim_of_small_steady_lights_is_not_taken_for_fireflies(monkeypatch):
    """Lights of 1000 (2 x 2 pixels, steady) on a lit base of 0.1, each with a rim of pixels that one sample in 8
    hits: the rim's pixels hold one hit each, as a firefly's do, but at the level of the light's steady inside
    (HEAVY_RATIO); without that test the frame around the lights is found."""
    rng = np.random.default_rng(4)
    n, shape = 8, (72, 72)
    mean = 0.1 * (1.0 + 0.05 * rng.standard_normal(shape))
    variance = (0.1 * 0.1) ** 2 * np.ones(shape)
    for y in range(8, 72, 18):
        for x in range(8, 72, 18):
            mean[y:y + 2, x:x + 2], variance[y:y + 2, x:x + 2] = 1000.0, 50.0**2
            rim = np.zeros(shape, dtype=bool)
            rim[y - 1:y + 3, x - 1:x + 3] = True
            rim[y:y + 2, x:x + 2] = False
            mean[rim] = (1000.0 + 7 * 0.1) / n
            variance[rim] = ((1000.0 - mean[rim]) ** 2 + 7 * (0.1 - mean[rim]) ** 2) / (n - 1)
    buffer = _buffer(np.full(shape, n), mean, variance)
    assert not rare_path_mask(buffer).any()
    monkeypatch.setattr(rare_paths, "HEAVY_RATIO", 0.0)
    assert rare_path_mask(buffer).mean() > 0.5


@pytest.mark.parametrize("n", [2, 4])
def test_a_noisy_base_whose_pixels_now_and_then_hold_one_large_sample_is_not_fireflies(n, monkeypatch):
    """Gamma samples (a squared coefficient of variation of 2, no rare hits) at 2 and 4 spp (2: the adaptive
    sampler's first round): some pixels hold most of their mean in one sample, far above the steady level beside
    them, but they do not hold the window's variance (HEAVY_SHARE; at 2 spp the other tests hold it off too)."""
    rng = np.random.default_rng(0)
    samples = rng.gamma(0.5, 2.0, (n, 96, 96))
    buffer = _buffer(np.full((96, 96), n), samples.mean(axis=0), samples.var(axis=0, ddof=1))
    assert not rare_path_mask(buffer).any()
    if n == 4:
        monkeypatch.setattr(rare_paths, "HEAVY_SHARE", 0.0)
        assert rare_path_mask(buffer).mean() > 0.5


def test_fireflies_that_hold_little_of_the_light_are_not_a_region(monkeypatch):
    """One sample in 3000 is 100 times the base: 3% of the light, what ranking them could take off the image mean at
    most; evening their region would cost more than that (HEAVY_LIGHT)."""
    buffer = _buffer(*_sparks(p=1 / 3000, n=32))
    assert not rare_path_mask(buffer).any()
    monkeypatch.setattr(rare_paths, "HEAVY_LIGHT", 0.0)
    assert rare_path_mask(buffer).mean() > 0.5


def test_one_or_two_fireflies_are_not_a_region(monkeypatch):
    """Samples 3000 times a lit base (8 spp): two in one window, 12 pixels apart, or one at an edge or a corner of
    the frame, are too few hits to tell a region (HEAVY_HITS; a window cut by the frame's edges counts what it
    holds, not copies of its edge blocks)."""
    samples = np.full(8, 0.5)
    samples[0] = 1500.0
    cases = {"two": ((40, 40), (40, 52)), "corner": ((0, 0),), "edge": ((0, 48),)}
    buffers = {}
    for name, places in cases.items():
        count, mean, variance = _sparks(p=0.0, n=8)
        for y, x in places:
            mean[y, x], variance[y, x] = samples.mean(), samples.var(ddof=1)
        buffers[name] = _buffer(count, mean, variance)
        assert not rare_path_mask(buffers[name]).any(), name
    monkeypatch.setattr(rare_paths, "HEAVY_HITS", 2)
    assert rare_path_mask(buffers["two"]).any()


def test_a_corner_window_needs_all_but_one_of_the_hits_not_its_share_alone():
    """A window cut by the frame's corner holds 5 x 5 of its 9 x 9 blocks, so its share of HEAVY_HITS is 1.2: two
    fireflies there would make a region that two anywhere else do not. Its least is all but one (3)."""
    samples = np.full(8, 0.5)
    samples[0] = 1500.0
    found = {}
    for name, places in {"two": ((2, 2), (2, 10)), "three": ((2, 2), (2, 10), (10, 2))}.items():
        count, mean, variance = _sparks(p=0.0, n=8)
        for y, x in places:
            mean[y, x], variance[y, x] = samples.mean(), samples.var(ddof=1)
        found[name] = rare_path_mask(_buffer(count, mean, variance))
    assert not found["two"].any()
    assert found["three"][:4, :4].all()


def test_a_window_over_a_last_partial_block_counts_its_pixels_not_whole_blocks():
    """97 rows: the last row of blocks holds one pixel row. The window of block row 22 holds 6 whole rows of blocks
    and that one (25 pixel rows, 900 pixels): its share of HEAVY_HITS is 2.8, so 3 hits make it a region; counted
    as whole blocks (28 rows) it would be 3.1, and need 4."""
    samples = np.full(8, 0.5)
    samples[0] = 1500.0
    count, mean, variance = _sparks(p=0.0, n=8, shape=(97, 96))
    for y, x in ((78, 40), (86, 52), (94, 46)):
        mean[y, x], variance[y, x] = samples.mean(), samples.var(ddof=1)
    mask = rare_path_mask(_buffer(count, mean, variance))
    assert mask[88:92, 44:56].all()


def test_pixels_of_unknown_variance_that_caught_a_firefly_do_not_hide_the_others():
    """An unknown variance is stored as 0: a pixel whose mean a firefly made would look steady at that level."""
    count, mean, variance = _sparks(n=8)
    known = np.random.default_rng(5).random((96, 96)) > 0.1
    buffer = SampleBuffer.from_moments(count, np.repeat(mean[..., None], 3, -1),
                                       np.repeat(np.where(known, variance, 0.0)[..., None], 3, -1),
                                       variance_known=known)
    assert rare_path_mask(buffer).mean() > 0.9


def test_a_pixel_the_ranking_gave_many_samples_weighs_as_one_pixel():
    """Seven pixels of a small disc that took 400 samples each (nine hits of 40 on a base of 1): a tenth of the
    window's samples' sum but 1% of its pixels' light, which is what ranking them can take off the image mean
    (HEAVY_LIGHT counts pixels' means, not samples)."""
    count, mean, variance = _sparks(p=0.0, n=8, base=1.0)
    samples = np.ones(400)
    samples[:9] = 40.0
    for y, x in ((40, 40), (40, 44), (44, 40), (44, 44), (48, 40), (48, 44), (40, 48)):
        count[y, x], mean[y, x], variance[y, x] = 400, samples.mean(), samples.var(ddof=1)
    assert not rare_path_mask(_buffer(count, mean, variance)).any()


def test_a_small_bright_steady_patch_does_not_hide_the_fireflies_around_it():
    """A steady 3 x 3 patch 14 times the base among fireflies of 100 times it: the hits beyond the blocks beside
    the patch are judged against the steady level beside them, not the patch's, so the frame outside the window
    around the patch is found (a firefly beside the patch is no hit, and its variance keeps that window out)."""
    for seed in range(3):
        count, mean, variance = _sparks(n=8, seed=seed)
        mean[46:49, 46:49], variance[46:49, 46:49] = 7.0, 0.01
        mask = rare_path_mask(_buffer(count, mean, variance))
        outside = np.ones(mask.shape, dtype=bool)
        outside[28:68, 28:68] = False
        assert mask[outside].mean() > 0.95, seed


def test_hits_gathered_in_a_small_disc_are_not_a_field_of_fireflies():
    """Four pixels with one hit each (400 times a steady base of 1, 8 spp), a seventh of their window's light: in
    four blocks they are a field of fireflies; gathered in one 2 x 2 square, a small disc of rare light, which
    ranking does not darken and evening costs its error (HEAVY_HITS counts separate hits, groups of touching
    pixels, wherever they lie on the blocks), also in a corner of the frame."""
    samples = np.ones(8)
    samples[0] = 400.0
    found = {}
    for name, places in (("spread", ((40, 40), (40, 52), (52, 40), (52, 52))),
                         ("gathered", ((40, 40), (40, 41), (41, 40), (41, 41))),
                         ("gathered across four blocks", ((39, 39), (39, 40), (40, 39), (40, 40))),
                         ("gathered in a corner", ((0, 0), (0, 1), (1, 0), (1, 1)))):
        count, mean, variance = _sparks(p=0.0, n=8, base=1.0)
        for y, x in places:
            mean[y, x], variance[y, x] = samples.mean(), samples.var(ddof=1)
        found[name] = rare_path_mask(_buffer(count, mean, variance))
    assert found["spread"][46, 46]
    for name in ("gathered", "gathered across four blocks", "gathered in a corner"):
        assert not found[name].any(), name


def test_the_rim_of_lights_one_pixel_wide_is_not_taken_for_fireflies():
    """Steady lights of one pixel (1000 on a base of 0.1, 8 spp) with a rim that one sample in 8 hits: the light's
    own steady level stands beside its rim, so the rim is a light's, not fireflies."""
    n, shape = 8, (72, 72)
    mean = np.full(shape, 0.1)
    variance = np.full(shape, 0.01**2)
    for y in range(8, 72, 12):
        for x in range(8, 72, 12):
            mean[y, x], variance[y, x] = 1000.0, 50.0**2
            rim = np.zeros(shape, dtype=bool)
            rim[y - 1:y + 2, x - 1:x + 2] = True
            rim[y, x] = False
            mean[rim] = (1000.0 + 7 * 0.1) / n
            variance[rim] = ((1000.0 - mean[rim]) ** 2 + 7 * (0.1 - mean[rim]) ** 2) / (n - 1)
    assert not rare_path_mask(_buffer(np.full(shape, n), mean, variance)).any()


@pytest.mark.parametrize("shape", [(66, 70), (67, 65), (5, 130)])
def test_the_last_partial_blocks_are_found_like_the_others(shape):
    mask = rare_path_mask(_buffer(*_hits(1 / 40, shape=shape, n=8)))
    assert mask[-1].all() and mask[:, -1].all() and mask.mean() > 0.95


def test_no_lit_pixel_no_counts_and_huge_values_find_nothing_or_stay_finite():
    assert not rare_path_mask(SampleBuffer.empty((5, 7))).any()
    assert not rare_path_mask(_buffer(np.full((9, 9), 4), np.zeros((9, 9)), np.zeros((9, 9)))).any()
    count, mean, variance = _hits(1 / 40, shape=(1, 3))
    assert rare_path_mask(_buffer(count, mean, variance)).shape == (1, 3)
    count, mean, _ = _hits(1 / 40)
    mean *= 1e300 / 40  # hits of 1e300, and variances near float64's top: the sums overflow
    with np.errstate(all="raise"):  # and raise no warning either
        mask = rare_path_mask(_buffer(count, mean, np.where(mean > 0, 1e307, 0.0)))
    assert mask.dtype == bool


@pytest.mark.parametrize("p, n", [(1 / 40, 8), (1 / 200, 4), (1 / 200, 8), (1 / 40, 32), (1 / 40, 128)])
def test_rarer_hits_fewer_samples_and_more_samples_are_all_found(p, n):
    """The backdrop's squares (BACKDROP) are too large for rare hits' zeros to fill at 4 spp, and a pixel's own
    variation counts at most OWN_COUNT samples: a region stays found as its pixels gather several hits."""
    assert rare_path_mask(_buffer(*_hits(p, shape=(96, 96), n=n))).mean() > 0.9


def test_a_bright_steady_beam_does_not_hide_the_region_around_it():
    """Steady pixels are left out of the pooled variation: a beam 3 pixels wide, 5 times the region's mean, with
    every sample lit, would otherwise raise the pooled mean of every window it crosses."""
    count, mean, variance = _hits(1 / 40, n=8)
    mean[:, 30:33], variance[:, 30:33] = 5.0, (0.25 * 5.0) ** 2
    assert rare_path_mask(_buffer(count, mean, variance)).mean() > 0.95


def test_signed_data_has_no_rare_paths():
    """Zero-mean noise has means near 0 beside its spread (a pooled CV2 in the thousands) but no rare hits."""
    rng = np.random.default_rng(3)
    mean = rng.normal(0.0, 0.5, (64, 64))
    assert not rare_path_mask(_buffer(np.full((64, 64), 4), mean, np.full((64, 64), 1.0))).any()


def test_fireflies_beside_levels_near_float64s_bottom_raise_nothing():
    """A lit base with fireflies, and pixels 1e-300 of the brightest (a variance near float64's least normal)."""
    count, mean, variance = _sparks(n=8)
    mean[:8, :8], variance[:8, :8] = 1e-300, 2.3e-308
    with np.errstate(all="raise"):
        mask = rare_path_mask(_buffer(count, mean, variance))
    assert mask[48:, 48:].all()


@pytest.mark.parametrize("scale", [1e-150, 1e-100, 1e100, 1e150])
@pytest.mark.parametrize("kind", ["zeros", "lit base"])
def test_the_same_hits_at_any_level_are_found_alike(scale, kind):
    count, mean, variance = _hits(1 / 40, n=8) if kind == "zeros" else _sparks(shape=(64, 64), n=8)
    expected = rare_path_mask(_buffer(count, mean, variance))
    with np.errstate(all="raise"):  # nothing under- or overflows on the way
        got = rare_path_mask(_buffer(count, mean * scale, variance * scale**2))
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("shape", [(1, 1), (1, 23), (23, 1), (7, 5), (40, 33)])
def test_the_dilation_and_the_window_counts_are_scipy_s_and_the_entries_sums(shape):
    """The search's own dilation (shifted copies or-ed) is scipy's maximum filter with edges repeated, and its window
    counts from running sums are the windows' entries summed (the reference forms, kept for these tests)."""
    from scipy import ndimage

    rng = np.random.default_rng(sum(shape))
    for density in (0.0, 0.02, 0.5, 1.0):
        mask = rng.random(shape) < density
        for size in (1, 3, 15):
            np.testing.assert_array_equal(rare_paths._dilated(mask, size),
                                          ndimage.maximum_filter(mask, size=size, mode="nearest"))
        counts = rng.integers(0, 17, size=shape)
        np.testing.assert_array_equal(rare_paths._counts_around(counts),
                                      rare_paths._zero_padded_window(counts.astype(np.float64)))


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (9, 1), (6, 4), (17, 25)])
def test_stacked_window_sums_are_each_sum_on_its_own(shape):
    """The search sums its block statistics stacked on a last axis, one call for all: each must come out exactly as
    it would alone (the same additions), with nothing padded or mixed along the stacked axis."""
    rng = np.random.default_rng(sum(shape))
    stats = [rng.random(shape) * 10.0 ** rng.integers(-3, 9) for _ in range(6)]
    stats[2][0, 0] = 1e16  # a firefly's block beside small ones
    for window in (rare_paths._window, rare_paths._zero_padded_window):
        stacked = window(np.stack(stats, axis=-1))
        for k, one in enumerate(stats):
            np.testing.assert_array_equal(stacked[..., k], window(one))


def test_each_region_takes_the_mean_of_its_densities_and_its_total_is_kept():
    count, mean, variance = _hits(1 / 40)
    mean[:, 20:44], variance[:, 20:44] = 1.0, 0.5  # two regions of rare hits, a steady band between them
    buffer = _buffer(count, mean, variance)
    density = np.random.default_rng(2).uniform(0.0, 2.0, (64, 64))
    mask = rare_path_mask(buffer)
    evened = even_rare_paths(density, buffer)
    left, right = mask[:, :16], mask[:, 48:]
    assert left.any() and right.any()
    assert np.unique(evened[:, :16][left]).size == 1 and np.unique(evened[:, 48:][right]).size == 1
    assert evened[:, :16][left][0] != evened[:, 48:][right][0]  # each region its own mean
    np.testing.assert_array_equal(evened[~mask], density[~mask])
    assert evened.sum() == pytest.approx(density.sum(), rel=1e-12)
    assert even_rare_paths(density, buffer, "ranked") is density


def test_an_unknown_choice_is_refused_by_name():
    with pytest.raises(ValueError, match="rare_paths: 'uniform' is not one of even, zeros, ranked"):
        even_rare_paths(np.ones((4, 4)), _buffer(*_hits(0.5, shape=(4, 4))), "uniform")
    for sampler in (AdaptiveSampler, VarianceSampler):
        with pytest.raises(ValueError, match="rare_paths"):
            sampler((8, 8), rare_paths="off")
    assert RARE_PATHS == ("even", "zeros", "ranked")


def _rare_scene(p=0.02, shape=(48, 48)):
    """Every sample 1 / p with chance p, else 0: a flat image of 1 lit through rare paths."""
    def image(x, y):
        return np.ones((x.size, 3))

    def noise(clean, x, y, u):
        return clean * np.where(u[:, 0] < p, 1.0 / p, 0.0)[:, None]

    return SyntheticScene("rare", shape, image, noise)


@pytest.mark.parametrize("sampler", [AdaptiveSampler, VarianceSampler])
def test_evened_rare_paths_keep_the_image_mean_that_ranking_them_loses(sampler):
    """docs/sampling.md, "Rare paths": ranked, the pixels whose first samples hit take more samples and are
    diluted, and the image comes out dark (about 5-10% here, 12 renders); evened, its mean is the scene's."""
    scene = _rare_scene()
    errors = {"even": [], "ranked": []}
    for seed in range(12):
        for choice in errors:
            buffer = sampler(scene.shape, seed=seed, rare_paths=choice).run(SyntheticRenderer(scene, seed=seed),
                                                                           total_spp=8)
            errors[choice].append(float(np.asarray(buffer.mean).mean()) - 1.0)
    even, ranked = np.array(errors["even"]), np.array(errors["ranked"])
    standard_error = even.std(ddof=1) / np.sqrt(even.size)
    assert abs(even.mean()) < max(3 * standard_error, 0.01), (even.mean(), standard_error)
    assert ranked.mean() < -0.03 and ranked.mean() < even.mean() - 3 * standard_error


@pytest.mark.parametrize("sampler", [AdaptiveSampler, VarianceSampler])
def test_fireflies_on_a_lit_base_keep_the_image_mean(sampler):
    """docs/sampling.md, "Fireflies on a lit base": the synthetic ``fireflies`` scene (40% of its light in one
    sample in 250) came out about 30% dark at 8 spp with its pixels ranked; evened, within the noise of its mean."""
    scene = make_scene("fireflies", (64, 64))
    reference = float(scene.reference().mean())

    def errors(choice):
        return np.array([float(np.asarray(sampler(scene.shape, seed=seed, rare_paths=choice).run(
            SyntheticRenderer(scene, seed=seed), total_spp=8).mean).mean()) / reference - 1.0 for seed in range(10)])

    even = errors("even")
    standard_error = even.std(ddof=1) / np.sqrt(even.size)
    assert abs(even.mean()) < max(3 * standard_error, 0.02), (even.mean(), standard_error)
    assert errors("zeros").mean() < -0.1


def test_a_density_that_is_not_finite_stays_and_is_left_out_of_its_regions_mean():
    buffer = _buffer(*_hits(1 / 40, n=8))
    density = np.full((64, 64), 2.0)
    density[5, 5], density[6, 6], density[7, 7] = np.nan, np.inf, 6.0
    evened = even_rare_paths(density, buffer)
    assert np.isnan(evened[5, 5]) and evened[6, 6] == np.inf
    finite = np.isfinite(density)
    assert evened[10, 10] == pytest.approx(density[finite].mean())
    huge = np.full((64, 64), 1e307)
    np.testing.assert_allclose(even_rare_paths(huge, buffer), huge, rtol=1e-12)  # its sum would overflow


def test_the_regions_sums_are_scipy_s_over_the_whole_image_bit_for_bit():
    """_evened sums each region over its finite pixels with bincount: the additions ndimage.sum makes over the
    whole image less its zeros, so the same floats (non-finite densities, -0.0 and levels near 1e308 included)."""
    from scipy import ndimage

    rng = np.random.default_rng(3)
    for trial in range(6):
        mask = rng.random((61, 83)) < 0.3
        density = rng.uniform(0.0, 2.0, mask.shape) * 10.0 ** rng.integers(-300, 300)
        density[rng.random(mask.shape) < 0.05] = (np.nan, np.inf, -0.0)[trial % 3]
        finite = mask & np.isfinite(density)
        labels, regions = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
        index = np.arange(1, regions + 1)
        unit = float(np.ldexp(1.0, int(np.frexp(np.max(np.abs(density[finite]), initial=1.0))[1]) - 1))
        with np.errstate(invalid="ignore", divide="ignore"):
            means = (ndimage.sum(np.where(finite, density / unit, 0.0), labels, index)
                     / ndimage.sum(finite, labels, index) * unit)
        expected = density.copy()
        expected[finite] = means[labels[finite] - 1]
        evened = rare_paths._evened(density, mask)
        np.testing.assert_array_equal(evened, expected)
        np.testing.assert_array_equal(np.signbit(evened), np.signbit(expected))


def test_a_density_of_another_shape_or_a_choice_that_is_no_name_is_refused():
    buffer = _buffer(*_hits(1 / 40, shape=(8, 8)))
    with pytest.raises(ValueError, match=r"density: shape \(8, 9\) is not the buffer's \(8, 8\)"):
        even_rare_paths(np.ones((8, 9)), buffer)
    with pytest.raises(TypeError, match="rare_paths"):
        even_rare_paths(np.ones((8, 8)), buffer, 1)
    assert even_rare_paths(np.ones((8, 8), dtype=np.int64), buffer, "ranked").dtype == np.float64
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(1) as pool:  # refused before any search starts on the pool, naming the argument
        for bad in (np.ones((8, 8)), None):
            with pytest.raises(TypeError, match="buffer: expected a SampleBuffer, got"):
                even_rare_paths(np.ones((8, 8)), bad)
            with pytest.raises(TypeError, match="buffer: expected a SampleBuffer, got"):
                with rare_paths.rare_path_evening(bad, "even", pool):
                    pass
        with pytest.raises(TypeError, match="executor: expected a concurrent.futures.Executor"):
            with rare_paths.rare_path_evening(buffer, "even", "pool"):
                pass


@pytest.mark.parametrize("choice", RARE_PATHS)
def test_the_search_beside_the_density_runs_on_the_executor_and_evens_alike(choice, monkeypatch):
    """rare_path_evening starts the search on the executor's thread (the samplers' ``ask()`` on two threads) and
    evens a density to the same bits as even_rare_paths; with no executor it searches in the caller's thread."""
    from concurrent.futures import ThreadPoolExecutor

    buffers = {"zeros": _buffer(*_hits(1 / 40)), "fireflies": _buffer(*_sparks())}
    threads = []
    real = rare_path_mask
    monkeypatch.setattr(rare_paths, "rare_path_mask",
                        lambda *a, **k: threads.append(threading.current_thread()) or real(*a, **k))
    for name, buffer in buffers.items():
        density = np.random.default_rng(1).uniform(0.0, 2.0, buffer.shape)
        expected = even_rare_paths(density, buffer, choice)
        threads.clear()
        with ThreadPoolExecutor(2) as pool:
            with rare_paths.rare_path_evening(buffer, choice, pool) as even:
                evened = even(density)
            np.testing.assert_array_equal(evened, expected)
            assert set(threads) <= set(pool._threads) and len(threads) == (choice != "ranked"), name
        threads.clear()
        with rare_paths.rare_path_evening(buffer, choice) as even:
            np.testing.assert_array_equal(even(density), expected)
        assert threads == ([threading.current_thread()] if choice != "ranked" else []), name
    assert (expected != density).any() or choice != "even"


@pytest.mark.parametrize("sampler", [AdaptiveSampler, VarianceSampler])
def test_the_samplers_search_on_their_executor(sampler, monkeypatch):
    from concurrent.futures import ThreadPoolExecutor

    threads = []
    real = rare_path_mask
    monkeypatch.setattr(rare_paths, "rare_path_mask",
                        lambda *a, **k: threads.append(threading.current_thread()) or real(*a, **k))
    buffer = _buffer(*_hits(1 / 40))
    with ThreadPoolExecutor(2) as pool:
        sampler.from_buffer(buffer, round=1, executor=pool).ask()
        assert len(threads) == 1 and threads[0] in pool._threads
    sampler.from_buffer(buffer, round=1).ask()
    assert threads[1:] == [threading.current_thread()]


def test_the_search_is_waited_for_when_the_density_fails(monkeypatch):
    """The caller may change the buffer once the block is left (a sampler's tell()): a search still reading it on
    another thread must have ended by then, the density's error or not."""
    from concurrent.futures import ThreadPoolExecutor

    ended = []
    real = rare_path_mask

    def slow(*args, **kwargs):
        time.sleep(0.3)
        ended.append(True)
        return real(*args, **kwargs)

    monkeypatch.setattr(rare_paths, "rare_path_mask", slow)
    with ThreadPoolExecutor(1) as pool:
        with pytest.raises(RuntimeError, match="the density failed"):
            with rare_paths.rare_path_evening(_buffer(*_hits(1 / 40)), "even", pool):
                raise RuntimeError("the density failed")
        assert ended == [True]


def test_a_window_of_fireflies_with_a_negative_mean_anywhere_is_no_region():
    """The same for fireflies on a lit base, over their larger windows (HEAVY_WINDOW blocks)."""
    count, mean, variance = _sparks(n=8)
    assert rare_path_mask(_buffer(count, mean, variance))[:24, :24].all()
    mean[:8, :8], variance[:8, :8] = -0.5, 0.0
    mask = rare_path_mask(_buffer(count, mean, variance))
    assert not mask[:24, :24].any() and mask[48:, 48:].all()


def test_a_window_with_a_negative_mean_anywhere_is_no_region():
    """Signed data: rare hits with a block of negative means beside them, away from every lit pixel."""
    count, mean, variance = _hits(1 / 40, n=8)
    found = rare_path_mask(_buffer(count, mean, variance))
    mean[:16, :16], variance[:16, :16] = -0.5, 0.0  # no lit pixel beside them: outside the pooled pixels
    mask = rare_path_mask(_buffer(count, mean, variance))
    assert found[:24, :24].all() and not mask[:16, :16].any() and mask[40:, 40:].all()
