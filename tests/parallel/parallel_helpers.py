"""Shared helpers of the parallel tests: reference (serial) computations and comparisons."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

import numpy as np

from awr_denoise import AdaptiveSampler, SampleBuffer, SampleRequest
from awr_denoise.io import read_image, write_sample_buffer
from awr_denoise.parallel import RendererSpec, denoise_frame
from awr_denoise.synthetic import SyntheticRenderer, make_scene

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


def serial_render(spec: RendererSpec, shape: tuple[int, int], total_spp: float, sampler_seed: int = 2) -> SampleBuffer:
    return AdaptiveSampler(shape, seed=sampler_seed).run(spec(), total_spp)


def write_dumps(directory, n_frames: int = 3, shape=(48, 64)) -> list:
    paths = []
    for frame in range(n_frames):
        path = directory / f"dump.{frame:04d}.exr"
        write_sample_buffer(path, noisy_buffer("edges", shape, spp=4, seed=frame))
        paths.append(path)
    return paths


def serial_frames(inputs, outputs, **options) -> None:
    """The reference: the same per-frame work, one frame after the other in this thread."""
    for source, target in zip(inputs, outputs):
        denoise_frame(source, target, **options)


def assert_same_files(a, b) -> None:
    for x, y in zip(a, b):
        np.testing.assert_array_equal(read_image(x), read_image(y), strict=True)
        assert x.read_bytes() == y.read_bytes()


@contextlib.contextmanager
def environ_restored() -> Iterator[None]:
    """This process' environment as it was, afterwards: starting a Dask cluster itself (as a user would), a test
    wrote the workers' settings into it (one BLAS and OpenMP thread among them), and every later test's
    subprocesses inherited them."""
    before = dict(os.environ)
    try:
        yield
    finally:
        os.environ.clear()
        os.environ.update(before)


def remakes_scratch(directory: str, seconds: float = 30.0) -> None:
    """What a Dask worker still starting does to its scratch folder (in a process of its own): makes it, and its
    locks, again and again, as each of its steps finds it missing."""
    import time
    from pathlib import Path

    end = time.monotonic() + seconds
    while time.monotonic() < end:
        with contextlib.suppress(OSError):
            space = Path(directory) / "dask-scratch-space"
            space.mkdir(parents=True, exist_ok=True)
            (space / "global.lock").touch()
        time.sleep(0.01)


def runs_through_stop_points(started: str, seconds: float = 120.0) -> int:
    """A long task of a worker (a frame's reconstruction): it passes a stop point every 10 ms, for ``seconds``
    unless one raises; ``started`` is made once it runs."""
    import time
    from pathlib import Path

    from awr_denoise._signals import stop_point

    Path(started).touch()
    end, passed = time.monotonic() + seconds, 0
    while time.monotonic() < end:
        stop_point()
        passed += 1
        time.sleep(0.01)
    return passed


def runs_until_stopped(started: str, ended: str, seconds: float = 120.0) -> int:
    """:func:`runs_through_stop_points`, making ``ended`` however it ends (a task on a cluster whose caller has
    gone: only a file tells that it stopped)."""
    from pathlib import Path

    try:
        return runs_through_stop_points(started, seconds)
    finally:
        Path(ended).touch()


def appears(path, seconds: float = 60.0) -> bool:
    """Whether ``path`` exists within ``seconds`` (a worker's task marks where it has got to with a file)."""
    import time
    from pathlib import Path

    end = time.monotonic() + seconds
    while not Path(path).exists():
        if time.monotonic() >= end:
            return False
        time.sleep(0.01)
    return True
