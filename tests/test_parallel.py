"""Parallel and distributed execution (awr_denoise.parallel) against serial runs.

Every parallel result is compared with the serial computation: frames and tiled renders bit for
bit, tiled reconstruction within the tolerance derived in docs/distributed.md. The Dask tests
start one local cluster of two worker processes on the loopback interface (module fixture,
about 1-2 s) and also run in the default test selection.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import dataclasses
import os
import sys

import numpy as np
import pytest
import pywt

from awr_denoise import AdaptiveSampler, Domain, SampleBuffer, SampleRequest, UniformSampler, reconstruct
from awr_denoise import parallel
from awr_denoise.parallel import (
    FramesFailedError,
    RendererSpec,
    TiledRenderer,
    add_executor_arguments,
    denoise_frames,
    executor_from_args,
    get_executor,
    halo_width,
    reconstruct_tiled,
    render_tiled,
    tile_grid,
)
from awr_denoise.synthetic import SyntheticRenderer, make_scene

distributed = pytest.importorskip("distributed")

# Tiled reconstruction is exact up to floating-point rounding (docs/distributed.md); this is
# the bound the tests hold it to, relative to the image's largest magnitude.
TILED_RTOL = 1e-12


def assert_same_buffer(a: SampleBuffer, b: SampleBuffer) -> None:
    """Bitwise equality of every statistic."""
    for name in ("count", "mean", "variance", "variance_known"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name, strict=True)
    assert a.channels == b.channels
    assert a.nonfinite == b.nonfinite


def assert_tiled_close(tiled: np.ndarray, whole: np.ndarray) -> None:
    assert tiled.shape == whole.shape
    error = np.abs(tiled - whole).max()
    assert error <= TILED_RTOL * np.abs(whole).max(), f"tiled differs from whole frame by {error:.3g}"


def noisy_buffer(scene: str = "hdr_source", shape: tuple[int, int] = (96, 136), spp: int = 4,
                 seed: int = 3) -> SampleBuffer:
    renderer = SyntheticRenderer(make_scene(scene, shape), seed=seed)
    return renderer(SampleRequest.uniform(shape, spp))


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A local Dask cluster: 2 worker processes, 1 thread each, loopback only, no dashboard.

    Its scheduler also writes a scheduler file, as ``dask scheduler --scheduler-file`` and
    dask-jobqueue do. ``dashboard_address=None`` turns the dashboard off, but the scheduler
    still serves its HTTP routes, by default on port 8787 with a warning when that port is
    taken; a free loopback port avoids both.
    """
    scheduler_file = tmp_path_factory.mktemp("dask") / "scheduler.json"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None,
                                  scheduler_kwargs={"dashboard_address": "127.0.0.1:0",
                                                    "scheduler_file": str(scheduler_file)}) as local:
        local.scheduler_file_path = scheduler_file
        yield local


@pytest.fixture
def dask_executor(cluster):
    with get_executor("dask", scheduler=cluster.scheduler_address) as executor:
        yield executor


# ---------------------------------------------------------------------------- executors
def test_get_executor_threads_and_processes_run_tasks():
    with get_executor("threads", workers=2) as threads:
        assert isinstance(threads, cf.ThreadPoolExecutor)
        assert list(threads.map(abs, [-3, 4])) == [3, 4]
    with get_executor("processes", workers=1) as processes:
        assert isinstance(processes, cf.ProcessPoolExecutor)
        assert processes.submit(abs, -5).result() == 5


def test_get_executor_defaults_to_threads_and_checks_its_arguments():
    with get_executor() as executor:
        assert isinstance(executor, cf.ThreadPoolExecutor)
    with pytest.raises(ValueError, match="kind"):
        with get_executor("ray"):
            pass
    with pytest.raises(ValueError, match="workers"):
        with get_executor("threads", workers=0):
            pass
    with pytest.raises(ValueError, match="scheduler"):
        with get_executor("threads", scheduler="tcp://127.0.0.1:8786"):
            pass


def test_dask_is_optional_with_an_install_hint(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    with pytest.raises(ImportError, match=r'pip install "awr-denoise\[dask\]"'):
        with get_executor("dask"):
            pass
    with get_executor("threads") as executor:  # nothing else needs Dask
        assert executor.submit(abs, -1).result() == 1


def test_executor_arguments_round_trip():
    parser = argparse.ArgumentParser()
    add_executor_arguments(parser)
    args = parser.parse_args(["--workers", "2"])
    with executor_from_args(args) as executor:
        assert isinstance(executor, cf.ThreadPoolExecutor)
        assert executor._max_workers == 2
    args = parser.parse_args(["--executor", "processes", "--workers", "1"])
    with executor_from_args(args) as executor:
        assert isinstance(executor, cf.ProcessPoolExecutor)
    with pytest.raises(ValueError, match="--scheduler"):
        executor_from_args(parser.parse_args(["--executor", "threads", "--scheduler", "tcp://127.0.0.1:1"]))
    with pytest.raises(ValueError, match="--workers"):
        executor_from_args(parser.parse_args(["--workers", "0"]))
    assert executor_from_args(argparse.Namespace()) is not None  # a parser without the options
    assert not parallel.executor_requested(parser.parse_args([]))
    assert parallel.executor_requested(parser.parse_args(["--executor", "threads"]))
    with_tile = argparse.ArgumentParser()
    add_executor_arguments(with_tile, tile_option=True)
    assert with_tile.parse_args([]).tile == 128 and with_tile.parse_args(["--tile", "64"]).tile == 64


def test_dask_executor_from_a_scheduler_address_leaves_the_cluster_running(cluster):
    parser = argparse.ArgumentParser()
    add_executor_arguments(parser)
    args = parser.parse_args(["--scheduler", cluster.scheduler_address])
    with executor_from_args(args) as executor:
        assert isinstance(executor, cf.Executor)
        assert sorted(executor.map(abs, [-2, 1])) == [1, 2]
    assert len(cluster.scheduler_info["workers"]) == 2  # still up for the next client


def test_dask_executor_from_a_scheduler_file(cluster):
    assert cluster.scheduler_file_path.is_file()
    with get_executor(scheduler=cluster.scheduler_file_path) as executor:
        assert executor.submit(abs, -7).result() == 7


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
    options = {"c_s": 1.0, "wavelet": wavelet, "levels": levels, "domain": "linear"}
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
def test_reconstruct_tiled_matches_whole_frame(mode, domain, wavelet, levels):
    buffer = noisy_buffer()
    options = {"c_s": 1.0, "wavelet": wavelet, "levels": levels, "domain": domain, "mode": mode}
    assert_tiled_close(reconstruct_tiled(buffer, tile=40, **options), reconstruct(buffer, **options))


def test_reconstruct_tiled_handles_empty_pixels_and_unknown_variance():
    rng = np.random.default_rng(7)
    shape = (100, 120)
    buffer = SampleBuffer.from_moments(rng.integers(0, 6, shape), rng.random(shape + (3,)), rng.random(shape + (3,)),
                                       variance_known=rng.random(shape) > 0.3)
    assert (buffer.count == 0).any() and not buffer.variance_known.all()
    for mode in ("channels", "luminance"):
        assert_tiled_close(reconstruct_tiled(buffer, tile=(30, 50), mode=mode), reconstruct(buffer, mode=mode))


def test_reconstruct_tiled_is_wrong_without_the_halo():
    buffer = noisy_buffer()
    whole = reconstruct(buffer, levels=3)
    error = np.abs(reconstruct_tiled(buffer, tile=40, levels=3, halo=0) - whole).max()
    assert error > 1e-3 * np.abs(whole).max()


@pytest.mark.parametrize("levels", [2, 3])
def test_halo_width_is_the_smallest_exact_halo(levels):
    buffer = noisy_buffer()
    whole = reconstruct(buffer, levels=levels)
    halo = halo_width("bior4.4", levels)
    assert_tiled_close(reconstruct_tiled(buffer, tile=40, levels=levels, halo=halo), whole)
    # One pixel less and a tile's edge pixel misses an input it depends on.
    assert np.abs(reconstruct_tiled(buffer, tile=40, levels=levels, halo=halo - 1) - whole).max() > \
        TILED_RTOL * np.abs(whole).max()


def test_reconstruct_tiled_is_wrong_without_a_global_domain_scale(monkeypatch):
    buffer = noisy_buffer()
    whole = reconstruct(buffer, levels=3)
    monkeypatch.setattr(parallel, "_global_domain", lambda domain, mean: Domain(domain))  # per-tile scale
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
            patch.setattr(parallel.cf, "wait", counting_wait)
            image = reconstruct_tiled(buffer, tile=tile, levels=levels, executor=executor)
    assert len(executor.largest) == len(tile_grid(buffer.shape, tile)) == 20
    assert executor.most_in_flight <= 2 * 2  # windows are cut as tasks finish, not all at once
    bound = tile + 2 * halo + 2**levels - 1  # the aligned start may add up to 2^L - 1 pixels
    assert all(s[0] <= bound and s[1] <= bound for s in executor.largest)
    assert max(s[0] * s[1] for s in executor.largest) < buffer.count.size
    assert_tiled_close(image, reconstruct(buffer, levels=levels))


def test_reconstruct_tiled_checks_its_arguments():
    buffer = noisy_buffer(shape=(32, 32))
    with pytest.raises(TypeError, match="buffer"):
        reconstruct_tiled(buffer.mean)
    with pytest.raises(ValueError, match="levels"):
        reconstruct_tiled(buffer, levels=9)
    with pytest.raises(ValueError, match="halo"):
        reconstruct_tiled(buffer, halo=-1)


# ---------------------------------------------------------------------------- tiled rendering
def serial_render(spec: RendererSpec, shape: tuple[int, int], total_spp: float, sampler_seed: int = 2) -> SampleBuffer:
    return AdaptiveSampler(shape, seed=sampler_seed).run(spec(), total_spp)


def test_render_tiled_equals_the_serial_render_bitwise():
    shape = (70, 90)
    spec = RendererSpec.synthetic("fireflies", shape, seed=5)
    expected = serial_render(spec, shape, 12)
    assert_same_buffer(render_tiled(spec, AdaptiveSampler(shape, seed=2), total_spp=12, tile=32), expected)
    assert_same_buffer(render_tiled(spec, AdaptiveSampler(shape, seed=2), total_spp=12, tile=(70, 13)), expected)


def test_render_tiled_differs_when_the_seed_differs():
    shape = (40, 40)
    expected = serial_render(RendererSpec.synthetic("edges", shape, seed=5), shape, 6)
    other = render_tiled(RendererSpec.synthetic("edges", shape, seed=6), AdaptiveSampler(shape, seed=2),
                         total_spp=6, tile=16)
    assert not np.array_equal(other.mean, expected.mean)


@dataclasses.dataclass(frozen=True)
class RequestOnlyFactory:
    """Builds a renderer that offers only ``__call__(request)`` (no per-sample entry point)."""

    spec: RendererSpec

    def __call__(self):
        inner = self.spec()
        return lambda request: inner(request)


def test_render_tiled_works_with_any_renderer():
    shape = (48, 40)
    spec = RendererSpec.synthetic("gradient", shape, seed=1)
    expected = UniformSampler(shape, seed=1).run(spec(), 6)
    with get_executor("threads", workers=2) as executor:
        tiled = render_tiled(RequestOnlyFactory(spec), UniformSampler(shape, seed=1), total_spp=6, tile=16,
                             executor=executor)
    assert_same_buffer(tiled, expected)


def test_tiled_renderer_builds_one_renderer_per_worker_thread():
    built = []

    def factory():
        built.append(1)
        return RendererSpec.synthetic("edges", (32, 32))()

    renderer = TiledRenderer(factory, tile=8)  # no executor: tiles in this thread, one after the other
    request = SampleRequest.uniform((32, 32), 2)
    assert_same_buffer(renderer(request), RendererSpec.synthetic("edges", (32, 32))()(request))
    renderer(request)
    assert len(built) == 1


def test_tiled_renderer_checks_its_arguments():
    with pytest.raises(TypeError, match="renderer_factory"):
        TiledRenderer(SyntheticRenderer(make_scene("edges", (8, 8))).scene)
    with pytest.raises(ValueError, match="tile"):
        TiledRenderer(RendererSpec.synthetic("edges", (8, 8)), tile=0)
    with pytest.raises(TypeError, match="executor"):
        TiledRenderer(RendererSpec.synthetic("edges", (8, 8)), executor="dask")
    with pytest.raises(ValueError, match="shape"):
        RendererSpec("synthetic", "edges")
    with pytest.raises(ValueError, match="kind"):
        RendererSpec("oidn", "edges", (8, 8))


# ---------------------------------------------------------------------------- frames
def write_dumps(directory, n_frames: int = 3, shape=(48, 64)) -> list:
    from awr_denoise.io import write_sample_buffer

    paths = []
    for frame in range(n_frames):
        path = directory / f"dump.{frame:04d}.exr"
        write_sample_buffer(path, noisy_buffer("edges", shape, spp=4, seed=frame))
        paths.append(path)
    return paths


def serial_frames(inputs, outputs, **options) -> None:
    """The reference: the same per-frame work, one frame after the other in this thread."""
    for source, target in zip(inputs, outputs):
        parallel._denoise_frame(str(source), str(target), False, False, {}, options)


def assert_same_files(a, b) -> None:
    from awr_denoise.io import read_image

    for x, y in zip(a, b):
        np.testing.assert_array_equal(read_image(x), read_image(y), strict=True)
        assert x.read_bytes() == y.read_bytes()


@pytest.fixture
def dumps(tmp_path):
    pytest.importorskip("OpenEXR")
    return write_dumps(tmp_path)


def test_denoise_frames_equals_the_serial_run_bitwise(tmp_path, dumps):
    options = {"c_s": 1.5, "wavelet": "bior4.4", "domain": "log"}
    serial = [tmp_path / f"serial.{i:04d}.exr" for i in range(len(dumps))]
    serial_frames(dumps, serial, **options)
    threaded = [tmp_path / f"threads.{i:04d}.exr" for i in range(len(dumps))]
    written = denoise_frames(dumps, threaded, **options)
    assert written == threaded
    assert_same_files(threaded, serial)
    from awr_denoise.io import read_image, read_sample_buffer

    np.testing.assert_array_equal(read_image(serial[1]),
                                  reconstruct(read_sample_buffer(dumps[1]), **options).astype(np.float32))


def test_denoise_frames_refuses_existing_outputs_before_any_work(tmp_path, dumps):
    outputs = [tmp_path / f"out.{i}.exr" for i in range(len(dumps))]
    outputs[2].write_bytes(b"keep me")
    with pytest.raises(FileExistsError, match="out.2.exr"):
        denoise_frames(dumps, outputs)
    assert not outputs[0].exists() and outputs[2].read_bytes() == b"keep me"
    denoise_frames(dumps, outputs, overwrite=True)
    assert outputs[2].read_bytes()[:4] == b"\x76\x2f\x31\x01"  # EXR magic number


def test_denoise_frames_reports_failed_frames_and_writes_the_others(tmp_path, dumps):
    broken = tmp_path / "broken.exr"
    broken.write_bytes(b"not an exr")
    inputs = [dumps[0], broken, dumps[2]]
    outputs = [tmp_path / f"out.{i}.exr" for i in range(3)]
    with pytest.raises(FramesFailedError, match="1 of 3") as info:
        denoise_frames(inputs, outputs)
    assert list(info.value.failures) == [str(broken)]
    assert outputs[0].exists() and outputs[2].exists() and not outputs[1].exists()
    assert not list(tmp_path.glob(".*.tmp*"))  # atomic writes leave no partial file


def test_denoise_frames_checks_its_arguments(tmp_path, dumps):
    with pytest.raises(ValueError, match="outputs"):
        denoise_frames(dumps, [tmp_path / "a.exr"])
    with pytest.raises(ValueError, match="more than once"):
        denoise_frames(dumps[:2], [tmp_path / "a.exr", tmp_path / "a.exr"])
    with pytest.raises(ValueError, match="also an input"):
        denoise_frames(dumps[:1], dumps[:1], overwrite=True)
    assert denoise_frames([], []) == []


# ---------------------------------------------------------------------------- on the Dask cluster
def test_cluster_render_tiled_equals_the_serial_render_bitwise(dask_executor):
    shape = (64, 80)
    spec = RendererSpec.synthetic("fireflies", shape, seed=11)
    expected = serial_render(spec, shape, 10)
    tiled = render_tiled(spec, AdaptiveSampler(shape, seed=2), total_spp=10, tile=32, executor=dask_executor)
    assert_same_buffer(tiled, expected)


def test_cluster_reconstruct_tiled_matches_whole_frame(dask_executor):
    buffer = noisy_buffer(shape=(120, 150))
    for mode in ("channels", "luminance"):
        whole = reconstruct(buffer, levels=3, mode=mode)
        assert_tiled_close(reconstruct_tiled(buffer, tile=48, levels=3, mode=mode, executor=dask_executor), whole)


def test_cluster_denoise_frames_equals_the_serial_run_bitwise(tmp_path, dumps, dask_executor):
    serial = [tmp_path / f"serial.{i}.exr" for i in range(len(dumps))]
    serial_frames(dumps, serial, c_s=1.0)
    clustered = [tmp_path / f"cluster.{i}.exr" for i in range(len(dumps))]
    denoise_frames(dumps, clustered, executor=dask_executor, c_s=1.0)
    assert_same_files(clustered, serial)


def test_local_cluster_on_demand_runs_a_tiled_render():
    shape = (32, 48)
    spec = RendererSpec.synthetic("edges", shape, seed=4)
    environ_before = os.environ.get("MALLOC_TRIM_THRESHOLD_")
    with get_executor("dask", workers=2) as executor:
        tiled = render_tiled(spec, AdaptiveSampler(shape, seed=2), total_spp=6, tile=16, executor=executor)
        # Workers keep glibc's malloc tuning (Dask's trim threshold made numpy tasks 1.7x slower).
        assert executor.submit(os.environ.get, "MALLOC_TRIM_THRESHOLD_").result() is None
    assert os.environ.get("MALLOC_TRIM_THRESHOLD_") == environ_before
    assert_same_buffer(tiled, serial_render(spec, shape, 6))


@pytest.mark.slow
@pytest.mark.tracer
def test_cluster_render_tiled_with_the_path_tracer_equals_the_serial_render(dask_executor):
    tracer = pytest.importorskip("awr_denoise.tracer")
    name = "cornell_box" if "cornell_box" in tracer.list_scenes() else sorted(tracer.list_scenes())[0]
    spec = RendererSpec.tracer(name, width=48, height=40, seed=3, threads=1)
    shape = spec().shape
    expected = AdaptiveSampler(shape, seed=1).run(spec(), 8)
    tiled = render_tiled(spec, AdaptiveSampler(shape, seed=1), total_spp=8, tile=24, executor=dask_executor)
    assert_same_buffer(tiled, expected)


def test_tasks_are_never_answered_from_dask_cache(cluster, tmp_path):
    """Dask reuses the result of an identical pure task; ours have side effects and must all run."""
    with distributed.Client(cluster.scheduler_address) as client:
        executor = client.get_executor()  # a user's executor, pure by default
        target = tmp_path / "made"
        futures = [parallel._submit(executor, os.mkdir, str(target)) for _ in range(2)]
        cf.wait(futures)
        outcomes = sorted(type(f.exception()).__name__ for f in futures)
        # Both ran, so one found the directory made; pure tasks would have shared one result.
        assert outcomes == ["FileExistsError", "NoneType"]
        executor.shutdown()


def test_process_pool_gives_the_serial_results(tmp_path, dumps):
    shape = (40, 56)
    spec = RendererSpec.synthetic("hdr_source", shape, seed=9)
    buffer = noisy_buffer(shape=(80, 100))
    serial = [tmp_path / f"serial.{i}.exr" for i in range(len(dumps))]
    serial_frames(dumps, serial)
    pooled = [tmp_path / f"pool.{i}.exr" for i in range(len(dumps))]
    with get_executor("processes", workers=2) as executor:
        denoise_frames(dumps, pooled, executor=executor)
        tiled = render_tiled(spec, AdaptiveSampler(shape, seed=2), total_spp=6, tile=24, executor=executor)
        image = reconstruct_tiled(buffer, tile=40, levels=3, executor=executor)
    assert_same_files(pooled, serial)
    assert_same_buffer(tiled, serial_render(spec, shape, 6))
    assert_tiled_close(image, reconstruct(buffer, levels=3))
