"""Synthetic renderers whose clean image is known: for tests, examples and benchmarks.

Each scene is an analytic image ``f(x, y)`` over the image plane (pixel units, x across the
columns) and a per-sample noise model. A sample at pixel ``(r, c)`` with index ``i`` looks at
``f`` at a sub-pixel position, so pixels across an edge get bimodal samples as they would from a
renderer, and its noise is drawn from numbers addressed by (seed, pixel, sample index,
dimension): the same samples come back however a request is split.

The reference of a scene is the box-filtered ``f`` (each pixel the average of ``f`` over its
area), estimated on a fine sub-pixel grid.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import _checks
from ._typing import FloatArray, Shape2D
from .buffers import SampleBuffer
from .parts import render_in_parts
from .requests import MAX_PART_SAMPLES, SampleRequest

__all__ = ["SyntheticScene", "SyntheticRenderer", "SCENES", "create_renderer", "list_scenes", "make_scene",
           "hash_uniform"]

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)


def _mix(x: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser: a bijective avalanche on uint64."""
    x = x ^ (x >> np.uint64(30))
    x = x * _M1
    x = x ^ (x >> np.uint64(27))
    x = x * _M2
    return x ^ (x >> np.uint64(31))


def hash_uniform(seed: int, pixel: np.ndarray, index: np.ndarray, dimension: int) -> FloatArray:
    """Uniform numbers in [0, 1) as a pure function of (seed, pixel, sample index, dimension).

    Examples
    --------
    The number of a sample does not depend on which other samples are drawn with it:

    >>> import numpy as np
    >>> from awr_denoise.synthetic import hash_uniform
    >>> together = hash_uniform(0, np.array([0, 0, 1]), np.array([0, 1, 0]), 0)
    >>> alone = hash_uniform(0, np.array([0]), np.array([1]), 0)
    >>> np.round(together, 4), bool(alone[0] == together[1])
    (array([0.4445, 0.3823, 0.5971]), True)
    >>> u = hash_uniform(7, np.zeros(10000, np.int64), np.arange(10000), 2)
    >>> bool(0 <= u.min() and u.max() < 1), round(float(u.mean()), 1)
    (True, 0.5)
    """
    seed = _checks.seed("seed", seed)
    with np.errstate(over="ignore"):
        key = _mix(np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(dimension + 1))
        h = _mix(pixel.astype(np.uint64) ^ key)
        h = _mix(h + index.astype(np.uint64) * np.uint64(0xD1B54A32D192ED03))
    return (h >> np.uint64(11)).astype(np.float64) * (1.0 / 9007199254740992.0)


@dataclass(frozen=True)
class SyntheticScene:
    """An analytic image and a noise model.

    Parameters
    ----------
    name
        Short identifier.
    shape
        (H, W) in pixels.
    image
        ``image(x, y) -> (N, 3)`` clean radiance at image-plane points (pixel units).
    noise
        ``noise(clean, x, y, u) -> (N, 3)`` one sample's value given the clean value there and
        two independent uniforms ``u`` of shape (N, 2); must have expectation ``clean``.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise.synthetic import make_scene
    >>> scene = make_scene("gradient", (4, 8))
    >>> scene.name, scene.shape
    ('gradient', (4, 8))
    >>> np.round(scene.image(np.array([0.0, 4.0]), np.array([0.0, 2.0])), 4)   # clean radiance at two points
    array([[0.2, 0.3, 0.5],
           [0.5, 0.5, 0.5]])
    >>> np.round(scene.reference()[0, :, 0], 4)                                # red rises across the columns
    array([0.2375, 0.3125, 0.3875, 0.4625, 0.5375, 0.6125, 0.6875, 0.7625])
    """

    name: str
    shape: Shape2D
    image: Callable[[FloatArray, FloatArray], FloatArray]
    noise: Callable[[FloatArray, FloatArray, FloatArray, FloatArray], FloatArray]

    def reference(self, supersampling: int = 32) -> FloatArray:
        """(H, W, 3) box-filtered clean image on a ``supersampling``-squared sub-pixel grid.

        The default grid of 32x32 points per pixel is fine enough that a pixel grazed by the
        ``hdr_source`` light (30, against 0.05 around it) gets its share: on an 8x8 grid a pixel
        covered by 1% of the light read 0.05 instead of about 0.35, and the plain mean's
        relMSE against that reference stopped falling above 256 spp.

        Examples
        --------
        Inside the ``edges`` scene's bright disc, and at a dark corner:

        >>> import numpy as np
        >>> from awr_denoise.synthetic import make_scene
        >>> reference = make_scene("edges", (8, 8)).reference()
        >>> reference.shape, np.round(reference[4, 2], 4), np.round(reference[0, 0], 4)
        ((8, 8, 3), array([0.8 , 0.72, 0.61]), array([0.1563, 0.1406, 0.1594]))
        """
        h, w = self.shape
        s = _checks.whole("supersampling", supersampling, minimum=1, maximum=64)
        offsets = (np.arange(s) + 0.5) / s
        acc = np.zeros((h, w, 3))
        rows, cols = np.mgrid[0:h, 0:w]
        for oy in offsets:
            for ox in offsets:  # s^2 whole-image evaluations; never a loop per pixel
                acc += self.image((cols + ox).ravel(), (rows + oy).ravel()).reshape(h, w, 3)
        return acc / (s * s)


class SyntheticRenderer:
    """A :class:`~awr_denoise.Renderer` (and :class:`~awr_denoise.requests.SampleTracer`) for a :class:`SyntheticScene`.

    Attributes
    ----------
    channels
        ``("R", "G", "B")``.
    stats
        ``samples`` traced, ``nonfinite`` (always 0: the noise models are finite) and
        ``seconds`` (0: not timed).

    Examples
    --------
    >>> from awr_denoise import SampleRequest
    >>> from awr_denoise.synthetic import make_scene, SyntheticRenderer
    >>> scene = make_scene("edges", (16, 16))
    >>> buf = SyntheticRenderer(scene)(SampleRequest.uniform(scene.shape, 4))
    >>> buf.total_samples
    1024
    """

    channels: tuple[str, ...] = ("R", "G", "B")

    def __init__(self, scene: SyntheticScene, *, seed: int = 0) -> None:
        self.scene = scene
        self.seed = _checks.seed("seed", seed)
        self.stats: dict[str, float] = {"samples": 0, "nonfinite": 0, "seconds": 0.0}

    @property
    def shape(self) -> Shape2D:
        """(H, W) of the image."""
        return self.scene.shape

    @property
    def samples_rendered(self) -> int:
        """Samples rendered so far."""
        return int(self.stats["samples"])

    def close(self) -> None:
        """Nothing to release."""

    def samples(self, request: SampleRequest) -> tuple[np.ndarray, FloatArray]:
        """Flat pixel indices and (N, 3) values of every sample the request asks for.

        Examples
        --------
        >>> from awr_denoise import SampleRequest
        >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
        >>> pixel, values = SyntheticRenderer(make_scene("edges", (4, 4))).samples(SampleRequest.uniform((4, 4), 2))
        >>> pixel[:4].tolist(), values.shape
        ([0, 0, 1, 1], (32, 3))
        """
        if request.shape != self.scene.shape:
            raise ValueError(f"request: shape {request.shape} does not match the scene's {self.scene.shape}")
        rows, cols, index = request.pixel_list()
        return rows * self.scene.shape[1] + cols, self._values(rows, cols, index)

    def trace_samples(self, rows: np.ndarray, cols: np.ndarray, sample_index: np.ndarray) -> FloatArray:
        """(N, 3) values of the given samples, one per ``(row, column, sample index)``.

        The same numbers :meth:`samples` gives for those samples, however they are grouped:
        a tile of the image can be rendered on its own (:mod:`awr_denoise.parallel`).

        Examples
        --------
        Sample 5 of pixel (2, 3) is the same number whether it is traced alone or as part of
        a request for samples 4 to 7 of every pixel:

        >>> import numpy as np
        >>> from awr_denoise import SampleRequest
        >>> from awr_denoise.synthetic import SyntheticRenderer, make_scene
        >>> renderer = SyntheticRenderer(make_scene("edges", (4, 4)), seed=3)
        >>> pixel, values = renderer.samples(SampleRequest.uniform((4, 4), 4, first_index=4))
        >>> alone = renderer.trace_samples(np.array([2]), np.array([3]), np.array([5]))
        >>> bool(np.array_equal(alone[0], values[(pixel == 2 * 4 + 3).nonzero()[0][1]]))
        True
        """
        rows, cols, sample_index = (np.asarray(a, np.int64).ravel() for a in (rows, cols, sample_index))
        h, w = self.scene.shape
        if np.any((rows < 0) | (rows >= h) | (cols < 0) | (cols >= w)):
            raise ValueError(f"rows, cols: pixel coordinates outside the {h}x{w} image")
        values = self._values(rows, cols, sample_index)
        self.stats["samples"] += rows.size
        return values

    def _values(self, rows: np.ndarray, cols: np.ndarray, index: np.ndarray) -> FloatArray:
        pixel = rows * self.scene.shape[1] + cols
        x = cols + hash_uniform(self.seed, pixel, index, 0)
        y = rows + hash_uniform(self.seed, pixel, index, 1)
        u = np.stack([hash_uniform(self.seed, pixel, index, 2), hash_uniform(self.seed, pixel, index, 3)], axis=1)
        clean = self.scene.image(x, y)
        return self.scene.noise(clean, x, y, u)

    def __call__(self, request: SampleRequest) -> SampleBuffer:
        if request.shape != self.scene.shape:
            raise ValueError(f"request: shape {request.shape} does not match the scene's {self.scene.shape}")
        return render_in_parts(request, self._render_part, MAX_PART_SAMPLES)  # a part's samples held at once

    def _render_part(self, first_row: int, part: SampleRequest) -> SampleBuffer:
        rows, cols, index = part.pixel_list()
        self.stats["samples"] += rows.size
        return SampleBuffer.from_samples(rows * part.shape[1] + cols, self._values(rows + first_row, cols, index),
                                         part.shape)


# ---------------------------------------------------------------------------- noise models
def _gaussian(sigma: Callable[[FloatArray, FloatArray, FloatArray], FloatArray]):
    def noise(clean, x, y, u):
        # Box-Muller from the two addressed uniforms; one normal shared by all channels, as a
        # path's throughput is shared by its colour channels.
        z = np.sqrt(-2.0 * np.log1p(-u[:, 0])) * np.cos(2 * np.pi * u[:, 1])
        return clean + (sigma(clean, x, y) * z)[:, None] * np.ones((1, 3))
    return noise


def _heavy_tailed(spike: float, probability: float):
    """Multiplicative noise with mean 1: rare samples ``spike`` times the mean (fireflies)."""
    low = (1.0 - spike * probability) / (1.0 - probability)

    def noise(clean, x, y, u):
        factor = np.where(u[:, 0] < probability, spike, low * (0.5 + u[:, 1]))
        return clean * factor[:, None]
    return noise


# ---------------------------------------------------------------------------- scenes
def _gradient(shape: Shape2D) -> SyntheticScene:
    h, w = shape

    def image(x, y):
        return np.stack([0.2 + 0.6 * x / w, 0.3 + 0.4 * y / h, 0.5 + 0.2 * np.sin(2 * np.pi * x / w)], axis=1)

    # Noise grows from left to right: smooth, position-dependent variance.
    return SyntheticScene("gradient", shape, image, _gaussian(lambda c, x, y: 0.05 + 0.5 * x / w))


def _edges(shape: Shape2D) -> SyntheticScene:
    h, w = shape

    def image(x, y):
        disc = ((x - 0.35 * w) ** 2 + (y - 0.5 * h) ** 2) < (0.22 * min(h, w)) ** 2
        bar = (x > 0.65 * w) & (x < 0.8 * w)
        base = 0.15 + 0.1 * y / h
        v = np.where(disc, 0.8, np.where(bar, 0.5, base))
        return np.stack([v, 0.9 * v, 0.7 * v + 0.05], axis=1)

    return SyntheticScene("edges", shape, image, _gaussian(lambda c, x, y: 0.15 + 0.0 * x))


def _hdr_source(shape: Shape2D) -> SyntheticScene:
    h, w = shape

    def image(x, y):
        r2 = (x - 0.5 * w) ** 2 + (y - 0.4 * h) ** 2
        source = r2 < (0.06 * min(h, w)) ** 2
        dark = 0.02 + 0.03 * np.exp(-r2 / (0.3 * min(h, w)) ** 2)
        v = np.where(source, 30.0, dark)
        return np.stack([v, v, 0.8 * v], axis=1)

    # Noise proportional to brightness (relative noise), as in a path tracer's light edges.
    return SyntheticScene("hdr_source", shape, image, _gaussian(lambda c, x, y: 0.6 * c[:, 1]))


def _fireflies(shape: Shape2D) -> SyntheticScene:
    h, w = shape

    def image(x, y):
        v = 0.3 + 0.2 * np.sin(3 * x / w) * np.cos(2 * y / h)
        step = np.where(x > 0.6 * w, 0.25, 0.0)
        return np.stack([v + step, v, v - 0.5 * step], axis=1)

    return SyntheticScene("fireflies", shape, image, _heavy_tailed(spike=100.0, probability=0.004))


def _rare_light(shape: Shape2D) -> SyntheticScene:
    h, w = shape
    cx, cy, radius = 0.3 * w, 0.35 * h, 0.02 * min(h, w)
    spike, probability = 40.0, 0.02

    def inside(x, y):
        return (x - cx) ** 2 + (y - cy) ** 2 < radius**2

    def image(x, y):
        v = np.where(inside(x, y), 1.0, 0.2 + 0.1 * x / w)
        return np.stack([v, v, 0.9 * v], axis=1)

    def noise(clean, x, y, u):
        # Inside the disc 80% of the radiance arrives through rare samples (a light seen through
        # a gap, a caustic): four samples of a pixel all miss it 92% of the time.
        p = np.where(inside(x, y), probability, 0.0)
        low = (1.0 - spike * p) / (1.0 - p)
        factor = np.where(u[:, 0] < p, spike, low * (0.5 + u[:, 1]))
        return clean * factor[:, None]

    return SyntheticScene("rare_light", shape, image, noise)


SCENES: dict[str, Callable[[Shape2D], SyntheticScene]] = {
    "gradient": _gradient,
    "edges": _edges,
    "hdr_source": _hdr_source,
    "fireflies": _fireflies,
    "rare_light": _rare_light,
}
"""Synthetic scenes: smooth noisy gradient, sharp edges, a 1000x bright source on a dark
background, heavy-tailed (firefly) samples 100x the mean, and a disc whose radiance mostly
arrives through rare samples (2%, 40x the mean) that a pixel's first samples usually miss."""


def make_scene(name: str, shape: Shape2D = (64, 64)) -> SyntheticScene:
    """Build a synthetic scene by name (one of :data:`SCENES`).

    Examples
    --------
    >>> from awr_denoise.synthetic import SCENES, make_scene
    >>> sorted(SCENES)
    ['edges', 'fireflies', 'gradient', 'hdr_source', 'rare_light']
    >>> make_scene("hdr_source", (48, 64)).shape
    (48, 64)
    """
    if name not in SCENES:
        raise ValueError(f"name: {name!r} is not one of {', '.join(sorted(SCENES))}")
    return SCENES[name](_checks.shape2d("shape", shape))


def list_scenes() -> list[str]:
    """Names of the synthetic scenes, as :func:`awr_denoise.renderers.renderer_scenes` lists them.

    Examples
    --------
    >>> from awr_denoise.synthetic import list_scenes
    >>> list_scenes()[:2]
    ['gradient', 'edges']
    """
    return list(SCENES)


def create_renderer(scene: str, *, shape: Shape2D | None = None, seed: int = 0) -> SyntheticRenderer:
    """Renderer factory of the registry (:mod:`awr_denoise.renderers`): a synthetic scene by name.

    Parameters
    ----------
    scene
        One of :data:`SCENES`.
    shape
        (H, W); required (synthetic scenes have no size of their own).
    seed
        Seed of the sample noise.

    Examples
    --------
    >>> from awr_denoise.synthetic import create_renderer
    >>> create_renderer("gradient", shape=(4, 8), seed=2).shape
    (4, 8)
    """
    if shape is None:
        raise ValueError("shape: a synthetic scene needs its (H, W)")
    return SyntheticRenderer(make_scene(scene, shape), seed=seed)
