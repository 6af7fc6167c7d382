"""``benchmarks/sampler_bias.py``: the previous ranking swapped in for a run, and the measurement of every variant."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
from scipy import ndimage

import awr_denoise.priorities as priorities
from awr_denoise import AdaptiveSampler, SampleBuffer, SampleRequest
from awr_denoise.synthetic import SyntheticRenderer, SyntheticScene, make_scene


@pytest.fixture(scope="module")
def bias(benchmark_script):
    return benchmark_script("sampler_bias")


def _buffer(seed=0, shape=(12, 10)):
    rng = np.random.default_rng(seed)
    mean = rng.uniform(0.5, 2.0, (*shape, 3))
    return SampleBuffer.from_moments(np.full(shape, 4), mean, rng.uniform(0.01, 1.0, (*shape, 3)) * mean**2)


def test_the_previous_ranking_is_swapped_in_for_the_block_and_back(bias):
    library = priorities.pooled_deviation
    buffer = _buffer()
    with bias.own_pixel_ranked():
        assert priorities.pooled_deviation is bias._pooled_with_own_pixel
        swapped = AdaptiveSampler.from_buffer(buffer, seed=0).density()
    assert priorities.pooled_deviation is library
    assert not np.allclose(swapped, AdaptiveSampler.from_buffer(buffer, seed=0).density())  # it reaches the sampler
    with contextlib.suppress(RuntimeError), bias.own_pixel_ranked():
        raise RuntimeError("the ranking comes back on an error too")
    assert priorities.pooled_deviation is library
    with bias.own_pixel_ranked(False):
        assert priorities.pooled_deviation is library


def test_the_previous_ranking_is_the_3x3_pool_of_both_terms(bias):
    buffer = SampleBuffer.from_moments(np.full((6, 6), 4), np.ones((6, 6, 3)), np.full((6, 6, 3), 0.25))
    var = np.full((6, 6), 0.25)
    var[2, 3] = 4.0
    flat = SampleBuffer.from_moments(np.full((6, 6), 4), np.ones((6, 6, 3)), np.repeat(var[..., None], 3, -1))
    got = bias._pooled_with_own_pixel(flat, "linear", absolute_above=None)
    np.testing.assert_allclose(got, np.sqrt(ndimage.uniform_filter(var, 3, mode="nearest")), rtol=1e-12)
    with_abs = bias._pooled_with_own_pixel(buffer, "linear")  # level 6 x the mean: 1/36 more
    np.testing.assert_allclose(with_abs, np.sqrt(0.25 * (1 + 1 / 36)), rtol=1e-12)


def test_every_variant_is_measured_against_uniform_sampling(bias):
    # A small light 1000 times its surroundings: ranked by every variant (the samplers even `fireflies` out now).
    scene = make_scene("hdr_source", (32, 32))
    reference = scene.reference()

    @contextlib.contextmanager
    def factory(seed):
        yield SyntheticRenderer(scene, seed=seed)

    row = bias.measure("hdr_source", factory, reference, [8], [0, 1])
    got = row["spp"]["8"]
    assert list(got) == ["uniform", *bias.VARIANTS]
    for values in got.values():
        assert set(values) == {"image_mean_error", "image_mean_error_sd", "relmse", "mse", "reconstruction_mean_change"}
        assert np.isfinite(list(values.values())).all() and values["relmse"] > 0
    # The variants sample differently from the default; the uniform runs are the renderer's own.
    assert len({got[k]["mse"] for k in bias.VARIANTS}) == len(bias.VARIANTS)
    plains = [np.asarray(SyntheticRenderer(scene, seed=s)(SampleRequest.uniform((32, 32), 8)).mean) for s in (0, 1)]
    assert got["uniform"]["mse"] == pytest.approx(np.mean([((p - reference) ** 2).mean() for p in plains]))
    assert got["uniform"]["image_mean_error"] == pytest.approx(np.mean([p.mean() / reference.mean() - 1
                                                                        for p in plains]))
    # The default's buffer is AdaptiveSampler's own, run as a user runs it.
    buffer = AdaptiveSampler((32, 32), seed=1).run(SyntheticRenderer(scene, seed=1), total_spp=8)
    assert got["default"]["image_mean_error"] != got["own pixel ranked"]["image_mean_error"]
    assert buffer.total_samples == 8 * 32 * 32


def test_the_table_has_a_row_per_scene_and_spp(bias):
    scene = make_scene("edges", (16, 16))

    @contextlib.contextmanager
    def factory(seed):
        yield SyntheticRenderer(scene, seed=seed)

    row = bias.measure("edges", factory, scene.reference(), [4], [0, 1, 2])
    results = {"seeds": [0, 1, 2], "renderers": {"synthetic": [row]}}
    head, rule, line = bias.table(results).split("\n")
    cells = line.strip("|").split("|")
    assert [c.strip() for c in cells[:3]] == ["synthetic", "edges", "4"]
    assert len(cells) == len(head.strip("|").split("|")) == 7 and rule.count("---") == 7
    for column in (3, 4):  # bias, then root mean square, of uniform and every variant
        assert len(cells[column].split("/")) == 1 + len(bias.VARIANTS) and cells[column].strip().endswith("%")
    assert len(cells[5].split("/")) == len(bias.VARIANTS) - 1  # over the default's


def test_the_root_mean_square_is_the_runs_own(bias):
    errors = np.array([0.01, -0.02, 0.04, 0.005])
    values = {"image_mean_error": errors.mean(), "image_mean_error_sd": errors.std(ddof=1) / 2}
    assert bias.rms_error(values, 4) == pytest.approx(np.sqrt((errors**2).mean()))


def _density(buffer, options):
    return AdaptiveSampler.from_buffer(buffer, seed=0, **options).density()


def test_only_the_neighbours_ranking_keeps_a_pixels_own_samples_from_its_rank(bias):
    """The routes: a pixel whose samples caught a bright path (mean 40x, variance 1600x) keeps its own density
    only when neither the absolute term nor the gain is there; each of them alone lets it through (1.6-2.7x
    here)."""
    buffer = _buffer(shape=(16, 16))
    mean, variance = np.array(buffer.mean), np.array(buffer.variance)
    mean[8, 8] *= 40.0
    variance[8, 8] *= 1600.0
    caught = SampleBuffer.from_moments(buffer.count, mean, variance)
    for label, options in bias.ROUTES.items():
        change = _density(caught, options) / _density(buffer, options)
        # every pixel moves a little with the image's mean level (the log domain's offset): the pixel's own
        # change is measured against the image's median one
        own = change[8, 8] / np.median(change)
        if label == "neighbours only":
            assert own == pytest.approx(1.0, abs=0.01), label
        else:
            assert own > 1.5, (label, own)


def test_the_routes_are_measured_and_tabled_like_the_variants(bias):
    scene = make_scene("fireflies", (16, 16))

    @contextlib.contextmanager
    def factory(seed):
        yield SyntheticRenderer(scene, seed=seed)

    row = bias.measure("fireflies", factory, scene.reference(), [4], [0, 1], bias.ROUTES)
    assert list(row["spp"]["4"]) == ["uniform", *bias.ROUTES]
    results = {"seeds": [0, 1], "variants": bias.ROUTES, "renderers": {"synthetic": [row]}}
    head, _, line = bias.table(results).split("\n")
    assert "neighbours only" in head and len(line.strip("|").split("|")[3].split("/")) == 1 + len(bias.ROUTES)


def _rare_scene():
    """Samples of 50 one time in 50, else 0: a flat image of 1 lit through rare paths, which the default evens."""
    def image(x, y):
        return np.ones((x.size, 3))

    def noise(clean, x, y, u):
        return clean * np.where(u[:, 0] < 0.02, 50.0, 0.0)[:, None]

    return SyntheticScene("rare", (32, 32), image, noise)


def test_rare_paths_add_uniform_samplings_reconstruction_and_table_every_method(bias):
    scene = _rare_scene()
    reference = scene.reference()

    @contextlib.contextmanager
    def factory(seed):
        yield SyntheticRenderer(scene, seed=seed)

    row = bias.measure("rare", factory, reference, [8], [0, 1], bias.RARE_PATH_VARIANTS, reconstruct_uniform=True)
    got = row["spp"]["8"]
    assert list(got) == ["uniform", "uniform, reconstructed", *bias.RARE_PATH_VARIANTS]
    # the reconstruction of uniform sampling's own buffers: its mean and how far it moved from theirs
    buffers = [SyntheticRenderer(scene, seed=s)(SampleRequest.uniform((32, 32), 8)) for s in (0, 1)]
    images = [bias.reconstruct(b) for b in buffers]
    expected = np.mean([((i - reference) ** 2).mean() for i in images])
    assert got["uniform, reconstructed"]["mse"] == pytest.approx(expected)
    assert got["uniform, reconstructed"]["reconstruction_mean_change"] == pytest.approx(
        np.mean([i.mean() / np.asarray(b.mean).mean() - 1 for i, b in zip(images, buffers)]))
    assert got["uniform"]["reconstruction_mean_change"] == 0.0
    results = {"seeds": [0, 1], "variants": bias.RARE_PATH_VARIANTS, "renderers": {"mitsuba": [row]}}
    head, rule, *lines = bias.rare_table(results).split("\n")
    assert len(lines) == 2 + len(bias.RARE_PATH_VARIANTS) and rule.count("---") == len(head.strip("|").split("|")) == 8
    methods = [line.split("|")[4].strip() for line in lines]
    assert methods[:2] == ["uniform", "uniform, reconstructed"]
    assert methods[2:] == [f"AWR sampling, {k}" for k in bias.RARE_PATH_VARIANTS]
    assert "rare paths ranked" in bias.RARE_PATH_VARIANTS and bias.RARE_PATH_VARIANTS["default"] == {}
    assert bias.RARE_PATH_VARIANTS["fireflies ranked"] == {"rare_paths": "zeros"}  # the default before fireflies
    # the ranked variant is the previous sampler: it samples this scene otherwise, and darker
    assert got["rare paths ranked"]["image_mean_error"] < got["default"]["image_mean_error"]


@pytest.mark.parametrize("argv, message", [(["--routes", "--rare-paths"], "give one"),
                                           (["--bundled"], "--bundled: only with --rare-paths"),
                                           (["--renderers", "synthetic"], "only with --rare-paths"),
                                           (["--rare-paths", "--renderers", "tracer"], "give --bundled")])
def test_rare_path_options_that_contradict_are_refused(bias, argv, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        bias.main(argv)
    assert exit_.value.code == 2 and message in capsys.readouterr().err


def test_the_reconstructions_change_of_a_black_buffers_mean_is_absolute(bias):
    assert bias._change(np.zeros((2, 2)), np.zeros((2, 2))) == 0.0
    assert bias._change(np.full((2, 2), 0.5), np.zeros((2, 2))) == 0.5
    assert bias._change(np.full((2, 2), 1.5), np.ones((2, 2))) == pytest.approx(0.5)


@pytest.mark.parametrize("argv, scenes, output", [
    (["--rare-paths"], {"mitsuba": "RARE_PATH_SCENES"}, "RARE_PATHS_RESULTS"),
    (["--rare-paths", "--bundled"], {"tracer": None, "mitsuba": "MITSUBA_SCENES"}, "RARE_PATHS_BUNDLED_RESULTS"),
    (["--rare-paths", "--renderers", "synthetic"], {"synthetic": None}, "RARE_PATHS_SYNTHETIC_RESULTS"),
    (["--rare-paths", "--renderers", "mitsuba", "synthetic"], {"mitsuba": "RARE_PATH_SCENES", "synthetic": None},
     "RARE_PATHS_RESULTS")])
def test_the_rare_path_modes_run_their_scenes_into_their_files(bias, monkeypatch, tmp_path, argv, scenes, output):
    ran, written = {}, {}

    def cases(renderer, names=None):
        ran[renderer] = names
        return iter(())

    monkeypatch.setattr(bias, "_tracer_cases", lambda: cases("tracer"))
    monkeypatch.setattr(bias, "_synthetic_cases", lambda: cases("synthetic"))
    monkeypatch.setattr(bias, "_mitsuba_cases", lambda names: cases("mitsuba", names))
    for name in ("RESULTS", "RARE_PATHS_RESULTS", "RARE_PATHS_BUNDLED_RESULTS", "RARE_PATHS_SYNTHETIC_RESULTS"):
        monkeypatch.setattr(bias, name, tmp_path / f"{name}.json")
    monkeypatch.setattr(bias, "rare_table", lambda results: written.setdefault("results", results) and "")
    assert bias.main([*argv, "--seeds", "2"]) == 0
    assert set(ran) == set(scenes)
    for renderer, names in scenes.items():
        assert ran[renderer] == (getattr(bias, names) if names else None)
    assert [p.name for p in tmp_path.iterdir()] == [f"{output}.json"]
    assert written["results"]["variants"] == bias.RARE_PATH_VARIANTS
