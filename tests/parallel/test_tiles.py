"""Tiled reconstruction (awr_denoise.parallel.tiles) against the whole-frame reconstruction.

Tiles are held to the tolerance derived in docs/distributed.md.
"""

from __future__ import annotations

import concurrent.futures as cf
from unittest import mock

import numpy as np
import pytest
import pywt

from awr_denoise import Domain, SampleBuffer, reconstruct
from awr_denoise.parallel import tiles
from awr_denoise.prepare import Prepared
from awr_denoise.parallel import (
    halo_width,
    reconstruct_tiled,
    tile_grid,
)
from parallel_helpers import (
    TILED_RTOL,
    assert_tiled_close,
    environ_restored,
    noisy_buffer,
)


# ---------------------------------------------------------------------------- tiles and halos
def test_tile_grid_covers_the_image_once():
    cover = np.zeros((70, 45), int)
    for rows, cols in tile_grid((70, 45), 32):
        cover[rows, cols] += 1
    assert (cover == 1).all()
    assert len(tile_grid((70, 45), (70, 45))) == 1
    with pytest.raises(ValueError, match="tile"):
        tile_grid((8, 8), 0)


def test_halo_width_is_the_wavelet_support():
    assert halo_width("haar", 1) == 1
    assert halo_width("db2", 3) == 3 * 7  # orthogonal: the bound (F - 1)(2^L - 1)
    assert halo_width("bior4.4", 5) == 7 * 31  # zero taps: below the bound 9 * 31
    for wavelet in ("haar", "db2", "sym4", "coif1", "bior2.2", "bior4.4"):
        for levels in (1, 2, 4):
            f = max(pywt.Wavelet(wavelet).dec_len, pywt.Wavelet(wavelet).rec_len)
            assert 0 < halo_width(wavelet, levels) <= (f - 1) * (2**levels - 1)
    with pytest.raises(ValueError, match="levels"):
        halo_width("haar", 0)


@pytest.mark.parametrize("wavelet", ["haar", "db2", "bior4.4"])
@pytest.mark.parametrize("levels", [1, 2, 3])
def test_halo_covers_the_measured_reach_of_reconstruction(wavelet, levels):
    """Perturb one pixel column at every phase of the 2^L grid: nothing beyond the halo moves."""
    rng = np.random.default_rng(levels)
    h, w, q0 = 16, 160, 64
    mean = 0.5 + 0.2 * rng.standard_normal((h, w, 1))
    count, var = np.full((h, w), 4), np.full((h, w, 1), 0.05)
    options = {"c_s": 1.0, "wavelet": wavelet, "levels": levels, "domain": "linear", "stages": 1}
    base = reconstruct(SampleBuffer.from_moments(count, mean, var), **options)
    reach = 0
    for q in range(q0, q0 + 2**levels):
        moved = mean.copy()
        moved[:, q] += 1.0
        changed = np.nonzero(np.abs(reconstruct(SampleBuffer.from_moments(count, moved, var), **options)
                                    - base).max(axis=(0, 2)) > 0)[0]
        reach = max(reach, q - changed.min(), changed.max() - q)
    assert reach == halo_width(wavelet, levels)


@pytest.mark.parametrize("mode", ["channels", "luminance"])
@pytest.mark.parametrize("domain", ["log", "linear", "gamma", Domain("log", robust=True)])
@pytest.mark.parametrize("wavelet,levels", [("bior4.4", 3), ("bior4.4", None), ("haar", 4), ("db2", 2)])
@pytest.mark.parametrize("stages", [1, 3])
def test_reconstruct_tiled_matches_whole_frame(mode, domain, wavelet, levels, stages):
    """Stage 1 in tiles, the Wiener stages on the assembled frame: in their float64 reference
    precision the whole result is the whole frame's to rounding."""
    buffer = noisy_buffer()
    options = {"c_s": 1.0, "wavelet": wavelet, "levels": levels, "domain": domain, "mode": mode, "stages": stages,
               "precision": "float64"}
    assert_tiled_close(reconstruct_tiled(buffer, tile=40, **options), reconstruct(buffer, **options))


def test_reconstruct_tiled_in_float32_is_the_whole_frame_to_float32_rounding():
    """The float32 FFTs see inputs that differ by rounding, so they round differently: held to the
    float32 tolerance of tests/test_reconstruct.py."""
    buffer = noisy_buffer()
    whole = reconstruct(buffer)
    assert np.abs(reconstruct_tiled(buffer, tile=40) - whole).max() <= 2e-6 * np.abs(whole).max()


def test_reconstruct_tiled_handles_empty_pixels_and_unknown_variance():
    rng = np.random.default_rng(7)
    shape = (100, 120)
    buffer = SampleBuffer.from_moments(rng.integers(0, 6, shape), rng.random(shape + (3,)), rng.random(shape + (3,)),
                                       variance_known=rng.random(shape) > 0.3)
    assert (buffer.count == 0).any() and not buffer.variance_known.all()
    for mode in ("channels", "luminance"):
        assert_tiled_close(reconstruct_tiled(buffer, tile=(30, 50), mode=mode, precision="float64"),
                           reconstruct(buffer, mode=mode, precision="float64"))


@pytest.mark.parametrize("mode", ["channels", "luminance"])
@pytest.mark.parametrize("stages", [1, 3])
def test_reconstruct_tiled_matches_whole_frame_where_samples_all_agreed(mode, stages):
    """Samples that are a hit or exactly 0 beside a black area, some pixels with one sample: the frame's
    preparation moderates the agreeing pixels' variances once and the tiles take them as they are. Before,
    each tile moderated them again (its neighbours now moderated too) and was 1e-4 to 8e-3 of the image's
    largest value off the whole frame."""
    rng = np.random.default_rng(3)
    shape = (64, 96)
    pixel = np.repeat(np.arange(shape[0] * shape[1]), 4)
    hits = (rng.random(pixel.size) < 0.1) & (pixel % shape[1] < 48)
    values = hits[:, None] * rng.uniform(1.0, 5.0, (pixel.size, 3))
    buffer = SampleBuffer.from_samples(pixel, values, shape)
    count = buffer.count.copy()
    count[::7, 40:56] = 1  # single samples at the band's edge
    buffer = SampleBuffer.from_moments(count, buffer.mean, buffer.variance)
    agreed = (buffer.variance == 0) & buffer.variance_known[..., None]
    assert agreed[:, 56:].all() and agreed[:, :48].any()
    options = {"mode": mode, "stages": stages, "precision": "float64"}
    assert_tiled_close(reconstruct_tiled(buffer, tile=32, **options), reconstruct(buffer, **options))


@pytest.mark.parametrize("mode", ["channels", "luminance"])
def test_reconstruct_tiled_treats_a_channel_beside_the_colour_as_reconstruct_does(mode):
    """R,G,B together and an alpha alone, in tiles as in the whole frame (the domain's scale of
    each group fixed before the tiles leave)."""
    rgb = noisy_buffer()
    h, w = rgb.shape
    alpha = np.clip(0.5 + 0.1 * np.random.default_rng(3).standard_normal((h, w, 1)), 0, 1)
    rgba = SampleBuffer.from_moments(rgb.count, np.concatenate([rgb.mean, alpha], 2),
                                     np.concatenate([rgb.variance, np.full((h, w, 1), 0.01)], 2),
                                     channels=("R", "G", "B", "A"))
    options = {"mode": mode, "precision": "float64"}
    tiled = reconstruct_tiled(rgba, tile=40, **options)
    assert_tiled_close(tiled, reconstruct(rgba, **options))
    assert_tiled_close(tiled[..., :3], reconstruct(rgb, **options))


def test_reconstruct_tiled_takes_the_guard_window():
    buffer = noisy_buffer("edges", shape=(64, 80), spp=8)
    for window in (9, 15):
        assert_tiled_close(reconstruct_tiled(buffer, tile=32, guard_window=window, precision="float64"),
                           reconstruct(buffer, guard_window=window, precision="float64"))
    assert not np.allclose(reconstruct_tiled(buffer, tile=32, guard_window=15), reconstruct(buffer))


def test_reconstruct_tiled_is_wrong_without_the_halo():
    buffer = noisy_buffer()
    whole = reconstruct(buffer, levels=3)
    error = np.abs(reconstruct_tiled(buffer, tile=40, levels=3, halo=0) - whole).max()
    assert error > 1e-3 * np.abs(whole).max()


@pytest.mark.parametrize("levels", [2, 3])
def test_halo_width_is_the_smallest_exact_halo(levels):
    """The halo serves stage 1, the part that runs in tiles."""
    buffer = noisy_buffer()
    whole = reconstruct(buffer, levels=levels, stages=1)
    halo = halo_width("bior4.4", levels)
    assert_tiled_close(reconstruct_tiled(buffer, tile=40, levels=levels, halo=halo, stages=1), whole)
    # One pixel less and a tile's edge pixel misses an input it depends on.
    assert np.abs(reconstruct_tiled(buffer, tile=40, levels=levels, halo=halo - 1, stages=1) - whole).max() > \
        TILED_RTOL * np.abs(whole).max()


def test_reconstruct_tiled_is_wrong_without_a_global_domain_scale(monkeypatch):
    buffer = noisy_buffer()
    whole = reconstruct(buffer, levels=3)
    # Tiles that bind the domain's scale to themselves instead of to the whole frame:
    monkeypatch.setattr(Prepared, "domain", property(lambda self: self.bound.domain))
    relative = np.abs(reconstruct_tiled(buffer, tile=40, levels=3) - whole) / np.abs(whole)
    assert relative.max() > 1e-2  # dark tiles around the bright source take a far smaller scale


class RecordingExecutor(cf.ThreadPoolExecutor):
    """A thread pool that records the largest array each task was given and the tasks in flight."""

    def __init__(self) -> None:
        super().__init__(max_workers=2)
        self.largest: list[tuple[int, ...]] = []
        self.in_flight = self.most_in_flight = 0

    def submit(self, fn, /, *args, **kwargs):
        shapes = [a.shape for a in args if isinstance(a, np.ndarray)]
        self.largest.append(max(shapes, key=lambda s: s[0] * s[1]))
        self.in_flight += 1  # submit and result collection both run in the caller's thread
        self.most_in_flight = max(self.most_in_flight, self.in_flight)
        return super().submit(fn, *args, **kwargs)

    def collected(self) -> None:
        self.in_flight -= 1


def test_reconstruct_tiled_sends_each_task_only_its_tile_and_halo():
    buffer = noisy_buffer(shape=(128, 160))
    tile, levels = 32, 2
    halo = halo_width("bior4.4", levels)
    with RecordingExecutor() as executor:
        real_wait = cf.wait

        def counting_wait(futures, **kwargs):
            done, pending = real_wait(futures, **kwargs)
            for _ in done:
                executor.collected()
            return done, pending

        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(tiles.cf, "wait", counting_wait)
            image = reconstruct_tiled(buffer, tile=tile, levels=levels, executor=executor, precision="float64")
    assert len(executor.largest) == len(tile_grid(buffer.shape, tile)) == 20
    assert executor.most_in_flight <= 2 * 2  # windows are cut as tasks finish, not all at once
    bound = tile + 2 * halo + 2**levels - 1  # the aligned start may add up to 2^L - 1 pixels
    assert all(s[0] <= bound and s[1] <= bound for s in executor.largest)
    assert max(s[0] * s[1] for s in executor.largest) < buffer.count.size
    assert_tiled_close(image, reconstruct(buffer, levels=levels, precision="float64"))


def test_reconstruct_tiled_checks_its_arguments():
    buffer = noisy_buffer(shape=(32, 32))
    with pytest.raises(TypeError, match="buffer"):
        reconstruct_tiled(buffer.mean)
    with pytest.raises(ValueError, match="levels"):
        reconstruct_tiled(buffer, levels=9)
    with pytest.raises(ValueError, match="halo"):
        reconstruct_tiled(buffer, halo=-1)


def test_a_worker_killed_mid_run_costs_its_tiles_a_second_try_not_the_reconstruction():
    """On a cluster, the tiles' windows are scattered by the client, and data scattered cannot be computed again: one
    worker SIGKILLed (its nanny starts another) failed the whole reconstruction with a bare CancelledError or the
    scatter's closed connection (an attack pass). A tile whose window went with a worker is sent again: the
    result is the whole-frame reconstruction's."""
    distributed = pytest.importorskip("distributed")
    import os
    import signal
    import threading
    import time

    from awr_denoise import SampleRequest
    from awr_denoise.parallel import get_executor
    from awr_denoise.parallel.executors import dask_client
    from awr_denoise.synthetic import SyntheticRenderer, make_scene

    shape = (512, 512)
    buffer = SyntheticRenderer(make_scene("edges", shape), seed=1)(SampleRequest.uniform(shape, 4))
    expected = reconstruct(buffer, stages=1)
    with environ_restored(), distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                                      host="127.0.0.1", dashboard_address=None, silence_logs=50,
                                                      scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}) as local:
        victim = next(iter(local.workers.values())).process.pid

        def kill() -> None:
            time.sleep(1.5)
            os.kill(victim, signal.SIGKILL)

        lost = []  # a tile sent again, or a scatter tried again: the path under test ran
        real_lost = tiles._lost

        def counted_lost(future):
            lost.append(real_lost(future))
            return lost[-1]

        with get_executor(scheduler=local.scheduler_address) as executor, \
                mock.patch.object(tiles, "_lost", counted_lost):
            client = dask_client(executor)
            real_scatter = client.scatter

            def counted_scatter(*args, **kwargs):
                try:
                    return real_scatter(*args, **kwargs)
                except OSError:
                    lost.append(True)
                    raise

            client.scatter = counted_scatter
            threading.Thread(target=kill, daemon=True).start()
            out = reconstruct_tiled(buffer, tile=32, executor=executor, stages=1)
    assert_tiled_close(out, expected)
    assert any(lost)
