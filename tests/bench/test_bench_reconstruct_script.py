"""``benchmarks/bench_reconstruct.py``'s variants of the default reconstruction."""

from __future__ import annotations

import argparse
import importlib

import numpy as np
import pytest

from awr_denoise import fused
from awr_denoise.bench import noisy_buffer
from awr_denoise.wavelets import default_levels

from .conftest import STORED, refused_before_any_work


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("bench_reconstruct")


def test_the_cheaper_variants_include_one_stage_at_either_exponent(bench):
    """``quality --cheaper`` compares one Wiener stage at the default's last exponent and at its first."""
    assert bench.CHEAPER["one Wiener stage"] == {"stages": 2, "wiener_exponents": (0.4,)}
    assert bench.CHEAPER["one Wiener stage, alpha 0.75"] == {"stages": 2, "wiener_exponents": (0.75,)}


@pytest.mark.parametrize("shape", [(64, 64), (128, 128), (256, 256)])
def test_one_wiener_level_fewer_is_the_default_one_level_shallower(bench, shape, monkeypatch):
    """The variant runs the library's later stages with the Wiener depth one less, stage 1 unchanged."""
    rec = importlib.import_module("awr_denoise.reconstruct")  # the module: the package's name is the function
    depths = []
    real = rec._wiener_stages
    monkeypatch.setattr(rec, "_wiener_stages", lambda *a, **k: depths.append(k["levels"]) or real(*a, **k))
    bench.fewer_wiener_levels(noisy_buffer(shape, smooth=0, noise=0))
    assert depths == [rec._wiener_levels(default_levels(shape)) - 1]


def test_shifts_adds_the_cycle_spun_decimated_stages(bench):
    """``--shifts`` measures the decimated Wiener stages over 1, 4 and 16 shifts (decimated_wiener.py)."""
    assert list(bench.SHIFTED) == [f"decimated Wiener stages, {n}" for n in ("1 shift", "4 shifts", "16 shifts")]
    assert [f.__name__ for f in bench.SHIFTED.values()] == [f"decimated_wiener_{n}" for n in (1, 4, 16)]


def test_agreed_held_exact_is_the_default_before_moderation_and_restores_it(bench):
    """``quality --compare``'s "agreed samples held exact": the default with ``AGREED_PRIOR`` 0, the prior put
    back afterwards (every later default in the run moderates again)."""
    from awr_denoise import pooling, reconstruct
    buffer = bench.agreed_buffers((64, 64))["hit or zero, 2 spp"]
    held = bench.agreed_held_exact(buffer)
    assert pooling.AGREED_PRIOR == 1.0
    assert not np.allclose(held, reconstruct(buffer))
    pooling_prior = pooling.AGREED_PRIOR
    try:
        pooling.AGREED_PRIOR = 0.0
        assert np.array_equal(held, reconstruct(buffer))
    finally:
        pooling.AGREED_PRIOR = pooling_prior


def test_clamp_pools_every_neighbour_is_the_default_before_the_test_and_restores_it(bench, monkeypatch):
    """``quality --compare``'s "clamp pools every neighbour": the default with ``finishing.POOL_CHANCE`` 0, the
    chance put back afterwards; on a dark line one pixel wide the two differ."""
    from awr_denoise import SampleBuffer, finishing, reconstruct
    rng = np.random.default_rng(0)
    truth = np.full((32, 32, 1), 100.0)
    truth[:, 16] = 0.01
    buffer = SampleBuffer.from_moments(np.full((32, 32), 8), truth * (1 + 0.2 * rng.standard_normal(truth.shape)),
                                       (0.5 * truth) ** 2)
    every = bench.clamp_pools_every_neighbour(buffer)
    assert finishing.POOL_CHANCE == 1e-3
    assert not np.allclose(every, reconstruct(buffer))
    monkeypatch.setattr(finishing, "POOL_CHANCE", 0.0)
    assert np.array_equal(every, reconstruct(buffer))


def _holed_checkerboard(fraction: float):
    from awr_denoise import SampleBuffer
    rng = np.random.default_rng(0)
    rows, cols = np.mgrid[0:32, 0:32]
    clean = (0.2 + 0.6 * ((rows // 4 + cols // 4) % 2))[..., None] * np.ones(3)
    mean = clean + clean / 4 * rng.standard_normal(clean.shape)
    sampled = rng.random((32, 32)) >= fraction
    return SampleBuffer.from_moments(np.where(sampled, 16, 0), np.where(sampled[..., None], mean, 0.0),
                                     np.where(sampled[..., None], clean**2, 0.0))


def test_the_empty_sections_forms_are_the_default_on_full_buffers_and_restore_it(bench):
    """``empty``'s compared forms (the guard counting pixels without samples; those pixels copied) differ from
    the default only where pixels have no samples, and leave the default's steps as they were."""
    from awr_denoise import reconstruct
    module = importlib.import_module("awr_denoise.reconstruct")
    guard = module.sure_blend
    full, holed = _holed_checkerboard(0.0), _holed_checkerboard(0.4)
    for form in (bench.empty_pixels_counted, bench.empty_copied):
        assert np.array_equal(form(full), reconstruct(full))
        assert not np.allclose(form(holed), reconstruct(holed))
        assert module.sure_blend is guard


def test_emptied_buffers_lose_the_pixels_their_layout_names(bench):
    full = _holed_checkerboard(0.0)
    for i, layout in enumerate(bench.EMPTY_LAYOUTS):
        buffer, sampled = bench._emptied(full, layout, np.random.default_rng(i))
        assert np.array_equal(buffer.count > 0, sampled) and np.array_equal(buffer.mean[sampled], full.mean[sampled])
        share = 1 - sampled.mean()
        expected = 0.5 if layout == "the right half" else int(layout.split("%")[0]) / 100
        assert abs(share - expected) < 0.06


@pytest.mark.parametrize("name", ["pilot clamped", "no energy floor", "agreed samples held exact",
                                  "clamp pools every neighbour"])
def test_every_compared_form_runs(bench, name):
    out = bench.COMPARED[name](noisy_buffer((32, 32)))
    assert out.shape == (32, 32, 3) and np.isfinite(out).all()


def test_agreed_buffers_have_the_agreeing_pixels_they_name(bench):
    buffers = bench.agreed_buffers((240, 240))
    black = buffers["black squares, 8 spp"]
    agreed = (black.variance == 0) & black.variance_known[..., None]
    assert agreed[:120, :120].all() and not agreed[:120, 120:].any()
    hits = buffers["hit or zero, 2 spp"]
    assert 0.7 < ((hits.variance == 0) & hits.variance_known[..., None]).mean() < 0.9


def test_the_agreed_section_times_every_case(bench, capsys):
    rows = bench.agreed_speed(["128x128"], 1)
    assert [r["buffer"] for r in rows] == ["black squares, 8 spp", "hit or zero, 2 spp", "hit or zero, 2-39 spp"]
    compiled = {"moderation, compiled", "ask(), compiled"} if "numba" in fused.available() else set()
    cases = {"moderation alone", "moderation, gathered only", "default", "agreed samples held exact", "ask()",
             "ask(), agreed samples held exact", "moderation, masks as before", "ask(), masks as before",
             "moderation, rims lend", "ask(), rims lend"}
    assert all(set(r["seconds"]) == cases | compiled for r in rows)
    out = capsys.readouterr().out
    assert "| 128x128 | hit or zero, 2 spp |" in out
    assert ("moderation, compiled" in out) == bool(compiled)


def test_rims_lend_looks_for_no_rim_and_puts_the_region_back(bench, monkeypatch):
    """The agreed section's "rims lend" cases: no light's rim is looked for past the test for two levels, as
    before the rims stopped lending, and ``rims.EDGE_BLOCK`` is the default's again afterwards."""
    from awr_denoise import pooling, rims
    calls = []
    real = rims.coverage_edges
    monkeypatch.setattr(rims, "coverage_edges", lambda *a, **k: calls.append(real(*a, **k)) or calls[-1])
    b = bench.agreed_buffers((64, 64))["hit or zero, 2 spp"]
    bench._rims_lend(lambda: pooling.estimated_variance(b.count, b.mean, b.variance, b.variance_known))
    assert calls == [None] and rims.EDGE_BLOCK == 2


def test_compiled_runs_with_the_compiled_moderation_and_puts_the_backend_back(bench, monkeypatch):
    """The agreed section's compiled cases: the moderation's compiled loop runs, and the backend is the
    environment's again afterwards (also when the call raises)."""
    from awr_denoise import pooling
    if "numba" not in fused.available():
        pytest.skip("numba is not installed (extra 'fast')")
    b = bench.agreed_buffers((64, 64))["hit or zero, 2-39 spp"]
    calls, before = [], fused.backend()
    real = pooling._compiled_moderation
    monkeypatch.setattr(pooling, "_compiled_moderation", lambda: calls.append(1) or real())
    bench._compiled(lambda: pooling.estimated_variance(b.count, b.mean, b.variance, b.variance_known))
    assert calls == [1] and fused.backend() == before
    with pytest.raises(ZeroDivisionError):
        bench._compiled(lambda: 1 / 0)
    assert fused.backend() == before


def test_gathered_only_is_the_moderation_without_the_outward_path_and_restores_it(bench, monkeypatch):
    """The agreed section's "gathered only": every entry offset by offset; the same values to rounding."""
    from awr_denoise import pooling
    b = bench.agreed_buffers((64, 64))["hit or zero, 2-39 spp"]
    args = (b.count, b.mean, b.variance, b.variance_known)
    paths = []
    real = pooling._scattered_at_zero
    monkeypatch.setattr(pooling, "_scattered_at_zero", lambda *a: paths.append("outward") or real(*a))
    gathered = bench._gathered_only(lambda: pooling.estimated_variance(*args))
    assert paths == [] and pooling._SCATTER_SHARE == 2.0
    np.testing.assert_allclose(pooling.estimated_variance(*args), gathered, rtol=1e-12)
    assert paths == ["outward"]


def test_masks_as_before_give_the_same_moderation_and_restore_the_helpers(bench, monkeypatch):
    """The agreed section's "masks as before": scipy's filter, the broadcast and the 3-D nonzero run instead of
    this version's helpers, with the same bits, and the helpers are put back."""
    from awr_denoise import pooling
    b = bench.agreed_buffers((64, 64))["black squares, 8 spp"]
    known = b.variance_known.copy()
    known[::7] = False  # some pixels unknown: the masks of known pixels are made
    args = (b.count, b.mean, b.variance, known)
    helpers = (pooling._near, pooling._in_pixels, pooling._nonzero)
    calls = []
    real = bench.ndimage.maximum_filter
    monkeypatch.setattr(bench.ndimage, "maximum_filter", lambda *a, **k: calls.append(1) or real(*a, **k))
    before = bench._masks_as_before(lambda: pooling.agreed_variance(*args))
    assert calls and (pooling._near, pooling._in_pixels, pooling._nonzero) == helpers
    np.testing.assert_array_equal(pooling.agreed_variance(*args).view(np.int64), before.view(np.int64))


def test_speed_times_the_compared_forms_it_is_given(bench):
    """``speed --compare`` and ``--probes``: a compared form that is a function is called, one that is a set of
    options is passed to ``reconstruct``."""
    rows = bench.speed(["128x128"], 1, ("clamp pools every neighbour", "pilot c_s 1.5", "guard probes 1"))
    assert {"default", "clamp pools every neighbour", "pilot c_s 1.5", "guard probes 1"} <= set(rows[0]["seconds"])
    assert all(v > 0 for v in rows[0]["seconds"].values())


def test_a_recorded_command_names_no_folder_or_file_of_this_machine(bench):
    """Results sections record their command with the cache, the images' folder and a trial's output hidden."""
    command = bench.recorded_command("bench_guides.py", ["quality", "--output", "trial.json", "--cache", "cache",
                                                         "--images", "img", "--spps", "8"])
    assert command == "benchmarks/bench_guides.py quality --output FILE --cache DIR --images DIR --spps 8"


def test_a_recorded_command_hides_the_folders_given_with_an_equals_sign_or_abbreviated(bench):
    """``--cache=X`` and ``--cach X`` (argparse takes both) were recorded as given, this machine's folders in a
    committed results file."""
    argv = ["quality", "--cache=cache/of/this/machine", "--outp", "t.json", "--spps", "8"]
    command = bench.recorded_command("bench_reconstruct.py", argv, argparse.Namespace(cache="cache/of/this/machine",
                                                                                       output="t.json"))
    assert command == "benchmarks/bench_reconstruct.py quality --cache=DIR --outp FILE --spps 8"
    # an abbreviation of another option (--i is --initials in this script, a flag) keeps its neighbour
    argv = ["quality", "--i", "--spps", "8"]
    assert bench.recorded_command("bench_reconstruct.py", argv, argparse.Namespace(cache="c", output="r.json")) \
        == "benchmarks/bench_reconstruct.py quality --i --spps 8"


def _renders(bench, cache, spps=(2, 4)):
    return bench.uniform_buffers("synthetic", "edges", (16, 16), spps, 0, cache)


def test_cached_buffers_are_read_back_as_rendered(bench, tmp_path):
    first = _renders(bench, tmp_path)
    again = _renders(bench, tmp_path)
    assert all(np.array_equal(first[s].mean, again[s].mean) and np.array_equal(first[s].count, again[s].count)
               for s in (2, 4))


def test_another_renders_buffer_under_a_cached_name_is_rendered_again(bench, tmp_path):
    """A 4-spp buffer copied under the 2-spp name (or another scene's) was measured as the named one, exit 0."""
    clean = _renders(bench, tmp_path)
    (tmp_path / "synthetic_edges_g0_s2.npz").write_bytes((tmp_path / "synthetic_edges_g0_s4.npz").read_bytes())
    with pytest.warns(UserWarning, match=r"synthetic_edges_g0_s2\.npz: another render's buffer .*made again"):
        again = _renders(bench, tmp_path)
    assert int(again[2].count.max()) == 2 and np.array_equal(again[2].mean, clean[2].mean)


@pytest.mark.parametrize("damage", ["cut", "old"])
def test_a_cached_buffer_cut_short_or_of_an_older_run_is_rendered_again(bench, tmp_path, damage):
    """A run stopped while it saved left a file that opened with its features missing, or one that did not open
    (every later run stopped with numpy's error); files saved before they said what they are may be either."""
    clean = _renders(bench, tmp_path)
    path = tmp_path / "synthetic_edges_g0_s4.npz"
    if damage == "cut":
        path.write_bytes(path.read_bytes()[:300])
    else:  # as the scripts saved buffers before: no "render" entry
        np.savez(path, count=clean[4].count, mean=clean[4].mean, variance=clean[4].variance)
    with pytest.warns(UserWarning, match=r"synthetic_edges_g0_s4\.npz: .*made again"):
        again = _renders(bench, tmp_path)
    assert np.array_equal(again[4].mean, clean[4].mean)
    assert not list(tmp_path.glob(".*.tmp"))


@pytest.mark.parametrize("argv, message", [
    (["quality", "--scenes", "cornel_box"], "--scenes: cornel_box not among default, chess_dof"),
    (["quality", "--spps", "0"], "argument --spps: must be >= 1, got 0"),
    (["quality", "--groups", "-1"], "argument --groups: must be >= 0, got -1"),
    (["seeds", "--scenes", "default"], "--scenes: default not among"),
])
def test_bad_options_are_refused_before_any_work_and_the_results_kept(bench, tmp_path, capsys, argv, message):
    """A misspelt scene measured nothing and wrote its section empty over the stored one; ``--spps 0`` failed
    after rendering, with a traceback."""
    refused_before_any_work(bench.main, argv, message, tmp_path, capsys)


@pytest.mark.parametrize("stored, argv, message", [
    ("[]", [], "not a results file"),
    (STORED, ["--output", "q.json/"], "which names a folder"),  # the last --output is taken: Path drops the /
])
def test_a_results_file_that_is_not_one_is_refused_before_any_work(bench, tmp_path, capsys, stored, argv, message):
    refused_before_any_work(bench.main, ["quality", "--scenes", "default", *argv], message, tmp_path, capsys, stored)
