"""Mitsuba 3 as a renderer of the ask/tell loop: :class:`MitsubaRenderer`.

A :class:`~awr_denoise.requests.SampleRequest` is rendered exactly and in one Dr.Jit launch: the
adapter lists the requested samples ``(row, column, sample index)``, generates one camera ray per
sample as Mitsuba's ``SamplingIntegrator`` does (a uniform position inside the pixel, the box
filter of radius 0.5; an aperture sample when the sensor needs one; a shutter time only when the
shutter is open for a non-zero interval), calls the scene integrator's ``sample()`` on the whole
wavefront and accumulates the radiance per pixel in float64 (the exact two-pass statistics of
:meth:`~awr_denoise.buffers.SampleBuffer.from_samples`, see :mod:`~awr_denoise.adapters._samples`).
The film is never used, so its reconstruction filter plays no part (a non-box filter is reported
once).

Randomness is addressed: every random number of a sample, the camera's and the integrator's, comes
from a PCG32 stream of its own, seeded from (seed, pixel, sample index). A sample therefore has the
same value however requests are grouped into rounds, tiles or launches (see
docs/integrate_mitsuba.md, "Reproducibility", for what this does and does not cover).

Mitsuba is an optional extra (``pip install 'awr-denoise[mitsuba]'``), imported when a renderer is
built. The fast path is the ``llvm_ad_rgb`` variant, which needs a shared libLLVM
(``apt-get install libllvm19`` on Debian/Ubuntu).
"""

from __future__ import annotations

import dataclasses
import inspect
import logging
import os
import re
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._typing import FloatArray, Shape2D
from ..buffers import SampleBuffer
from ..errors import InputFileError
from ..features import feature_names
from ..requests import SampleRequest
from ._mitsuba_runtime import DEFAULT_VARIANT, import_mitsuba, variant_of_scene, variant_scope
from ._samples import Chunk, PixelStatistics, aligned_u32, sample_chunks
from .mitsuba_files import scene_files
from .mitsuba_scenes import ALL_SCENES, scene_dict

__all__ = ["MitsubaRenderer", "create_renderer", "list_features", "list_scenes", "scene_files", "FEATURES",
           "DEFAULT_BATCH_SIZE", "DEFAULT_VARIANT"]

logger = logging.getLogger(__name__)

DEFAULT_BATCH_SIZE = 1 << 22
"""Most samples traced in one launch; larger requests are split. A launch peaks at about 35 bytes
a sample (150 MB at this size; docs/integrate_mitsuba.md has the command that measures it)."""

FEATURES: dict[str, tuple[str, tuple[str, ...]]] = {
    "albedo": ("albedo", ("R", "G", "B")),
    "normal": ("sh_normal", ("X", "Y", "Z")),
    "depth": ("depth", ("Z",)),
}
"""Per-sample features of the first hit: name -> (Mitsuba ``aov`` type, channels). ``normal`` is the
shading normal in world space; ``depth`` is the distance from the camera plane along the view axis
(Mitsuba's distance along the ray times the ray's cosine to that axis, the project's convention of
:mod:`awr_denoise.features`); both are 0 where the ray leaves the scene, as in Mitsuba's ``aov``
integrator. Unlike the bundled tracer, the first hit is reported even on a mirror or glass."""

_U32 = 1 << 32
_REFUSED_INTEGRATORS = ("AOVIntegrator", "MomentIntegrator")


def _seed_words(seed: int) -> tuple[int, int, int, int]:
    """Four 32-bit words from the render seed (SplitMix64), salting the per-sample stream keys."""
    words = []
    x = (int(seed) * 0x9E3779B97F4A7C15 + 0x2545F4914F6CDD1D) & 0xFFFFFFFFFFFFFFFF
    for _ in range(2):
        x = (x + 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF
        z = x
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
        z ^= z >> 31
        words += [z & 0xFFFFFFFF, z >> 32]
    return words[0], words[1], words[2], words[3]


_SAMPLER_CLASSES: dict[str, type] = {}


def _addressed_sampler_class(mi: Any, dr: Any, variant: str) -> type:
    """A Python ``mi.Sampler`` drawing every number of a sample from that sample's own PCG32 stream.

    Mitsuba's own samplers seed their streams from the lane index of the wavefront, so a sample's
    numbers would depend on where it sits in the launch; this one is keyed by the sample itself.
    """
    if variant in _SAMPLER_CLASSES:
        return _SAMPLER_CLASSES[variant]

    class AddressedSampler(mi.Sampler):
        def __init__(self, rng: Any = None) -> None:
            super().__init__(mi.Properties())
            self.rng = mi.PCG32() if rng is None else rng

        def next_1d(self, active: Any = True) -> Any:
            return self.rng.next_float32(active)

        def next_2d(self, active: Any = True) -> Any:
            x = self.rng.next_float32(active)
            y = self.rng.next_float32(active)
            return mi.Point2f(x, y)

        def fork(self) -> Any:
            return AddressedSampler()

        def clone(self) -> Any:
            return AddressedSampler(mi.PCG32(self.rng))

        def schedule_state(self) -> None:
            dr.schedule(self.rng)

        def to_string(self) -> str:
            return "AddressedSampler[]"

    _SAMPLER_CLASSES[variant] = AddressedSampler
    return AddressedSampler


class MitsubaRenderer:
    """A Mitsuba 3 scene as a :class:`~awr_denoise.requests.Renderer` (channels R, G, B).

    Parameters
    ----------
    scene
        A Mitsuba XML file (path), a Mitsuba scene dict, a loaded ``mitsuba.Scene``, or the name of
        a bundled scene (:data:`~awr_denoise.adapters.mitsuba_scenes.ALL_SCENES`).
    shape
        (H, W) of the image; default the film's size. A file or dict is loaded with its film
        resized; a loaded scene cannot be resized.
    seed
        Render seed: different seeds give independent renders.
    variant
        Mitsuba variant, a JIT RGB one (``"llvm_ad_rgb"``, the default, or ``"cuda_ad_rgb"``). A
        loaded scene keeps its own variant.
    sensor
        Index of the scene's sensor to render through.
    batch_size
        Most samples per launch; a larger request is rendered in several launches whose
        statistics are merged exactly.
    params
        Parameters of a Mitsuba XML file (``$name`` substitutions), as for ``mi.load_file``.
    features
        Features every request also returns in ``SampleBuffer.features`` (names of
        :data:`FEATURES`, a comma-separated string or ``"all"``; default none), from Mitsuba's
        ``aov`` integrator on the same camera rays as the radiance.

    Attributes
    ----------
    channels
        ``("R", "G", "B")``: linear sRGB radiance, as Mitsuba's RGB variants compute it.
    seed
        The render seed; it may be changed between calls (it is a kernel input, so a new seed
        compiles nothing).
    shape
        (H, W) of the image (the film's crop window).
    scene
        The loaded ``mitsuba.Scene``.
    stats
        Running totals: ``samples``, ``nonfinite`` (samples whose radiance was NaN/Inf and was
        replaced by 0, as the bundled tracer does), ``launches`` and ``seconds``.

    Notes
    -----
    Per request: list the samples, seed one PCG32 stream per sample from (seed, pixel, sample
    index), draw the pixel position (and the aperture and time samples when the sensor needs
    them) from it, ``sensor.sample_ray_differential``, the scene integrator's ``sample()`` on the
    wavefront, read the radiance back and accumulate it per pixel in float64. Ray differentials
    span one pixel (Mitsuba's footprint at 1 spp; no built-in plugin reads them for radiance).
    The first calls compile Dr.Jit kernels (seconds); later calls reuse them.

    Examples
    --------
    >>> from awr_denoise import AdaptiveSampler
    >>> from awr_denoise.adapters.mitsuba import MitsubaRenderer
    >>> renderer = MitsubaRenderer("cornell_box", shape=(32, 32), seed=1)  # doctest: +SKIP
    >>> buffer = AdaptiveSampler(renderer.shape).run(renderer, total_spp=8)  # doctest: +SKIP
    >>> buffer.total_samples  # doctest: +SKIP
    8192
    """

    channels: tuple[str, ...] = ("R", "G", "B")

    def __init__(self, scene: Any, *, shape: Shape2D | None = None, seed: int = 0,
                 variant: str = DEFAULT_VARIANT, sensor: int = 0, batch_size: int = DEFAULT_BATCH_SIZE,
                 params: dict[str, Any] | None = None,
                 features: tuple[str, ...] | str | None = None) -> None:
        self.features = feature_names(features)
        if isinstance(seed, bool) or int(seed) < 0 or int(seed) != seed:
            raise ValueError(f"seed: {seed!r} must be a whole number >= 0")
        if not 1 <= int(batch_size) < _U32:
            raise ValueError(f"batch_size: {batch_size} must be >= 1 and below 2**32")
        if shape is not None:
            shape = tuple(int(s) for s in shape)  # type: ignore[assignment]
            if len(shape) != 2 or min(shape) <= 0:
                raise ValueError(f"shape: expected (H, W) with both > 0, got {shape}")
        self.seed = int(seed)
        self.batch_size = int(batch_size)
        mi, dr = import_mitsuba(variant)
        scene_variant = variant_of_scene(mi, scene)
        self.variant = scene_variant or variant
        if scene_variant is not None and scene_variant != variant:
            mi, dr = import_mitsuba(scene_variant)
        self._mi, self._dr = mi, dr
        with variant_scope(mi, self.variant):
            self.scene, self.name = self._load(scene, shape, params)
            sensors = self.scene.sensors()
            if not 0 <= int(sensor) < len(sensors):
                raise ValueError(f"sensor: {sensor} is not a sensor index of {self.name} ({len(sensors)} sensor(s))")
            self.sensor = sensors[int(sensor)]
            film = self.sensor.film()
            crop = film.crop_size()
            self._shape: Shape2D = (int(crop[1]), int(crop[0]))
            if min(self._shape) < 1:  # Mitsuba takes a film of width 0; a request of it named "counts"
                raise ValueError(f"{self.name}: its film (crop) is {self._shape[1]}x{self._shape[0]} pixels; "
                                 "a film needs at least 1x1")
            if shape is not None and shape != self._shape:
                raise ValueError(f"shape: {shape} differs from the film of {self.name} ({self._shape}); "
                                 "a loaded mitsuba.Scene cannot be resized, pass its file or dict instead")
            rfilter = film.rfilter()
            self.integrator = self.scene.integrator()
            if self.integrator is None:
                raise ValueError(f"{self.name}: the scene declares no integrator; the adapter needs a sampling "
                                 "integrator (e.g. <integrator type=\"path\"/>)")
            if not isinstance(self.integrator, mi.SamplingIntegrator):
                raise ValueError(f"{self.name}: integrator {self.integrator.class_name()} is not a sampling integrator; "
                                 "the adapter needs one that estimates radiance along a ray (e.g. 'path')")
            if self.integrator.class_name() in _REFUSED_INTEGRATORS:
                raise ValueError(f"{self.name}: integrator {self.integrator.class_name()} writes AOVs or moments, "
                                 "not radiance; give the scene its inner integrator (e.g. 'path')")
            if not rfilter.is_box_filter():  # once the scene is known to be usable: a refused one says only why
                kind = _FILTER_PLUGINS.get(rfilter.class_name(), rfilter.class_name())
                warnings.warn(f"{self.name}: the film's {kind} filter is not used; every sample is rendered into "
                              "its own pixel (box filter of radius 0.5), as AWR needs", stacklevel=_caller_level())
            # Integrators written in Python on Mitsuba's AD base class take (mode, scene, sampler, ray, ...).
            self._python_ad = isinstance(self.integrator, mi.CppADIntegrator) and \
                "mode" in inspect.signature(type(self.integrator).sample).parameters
            self._needs_aperture = bool(self.sensor.needs_aperture_sample())
            self._shutter_open = float(self.sensor.shutter_open())
            self._shutter_time = float(self.sensor.shutter_open_time())
        self._sampler_class = _addressed_sampler_class(mi, dr, self.variant)
        self._feature_integrators: dict[tuple[str, ...], Any] = {}
        self._constants: dict[str, Any] = {}
        self._seed_cache: tuple[int | None, Any] = (None, ())
        self.stats: dict[str, float] = {"samples": 0, "nonfinite": 0, "launches": 0, "seconds": 0.0}

    # ------------------------------------------------------------------ loading
    def _load(self, scene: Any, shape: Shape2D | None, params: dict[str, Any] | None) -> tuple[Any, str]:
        mi = self._mi
        if isinstance(scene, mi.Scene):
            return scene, "scene"
        if isinstance(scene, dict):
            return mi.load_dict(_resized(scene, shape)), str(scene.get("id", "scene dict"))
        if isinstance(scene, (str, os.PathLike)):
            path = Path(scene)
            if isinstance(scene, str) and scene in ALL_SCENES and not path.exists():
                return mi.load_dict(scene_dict(scene, shape, variant=self.variant)), scene
            if not path.is_file():
                raise FileNotFoundError(f"{scene}: no such Mitsuba scene file (bundled scenes: {', '.join(ALL_SCENES)})")
            try:
                loaded = _load_file(mi, self.variant, path, shape, params or {})
            except RuntimeError as exc:  # Mitsuba's parser: a bad plugin, parameter, include or file
                raise InputFileError(f"{path}: Mitsuba cannot load this scene: {_parser_message(exc)}") from None
            except UnicodeDecodeError:  # Mitsuba's message quoted bytes of a file that are not text
                raise InputFileError(f"{path}: Mitsuba cannot load this scene: a file it reads is not what the "
                                     "scene declares (its error quotes bytes that are not text)") from None
            # A scene file's numbers only: a dict or a loaded scene is the caller's own, an Inf radiance
            # there a way to test the non-finite samples' policy.
            _refuse_nonfinite(mi, loaded, str(path))
            return loaded, path.name
        raise TypeError(f"scene: expected a Mitsuba XML path, scene dict, mitsuba.Scene or bundled scene name, "
                        f"got {type(scene).__name__}")

    # ------------------------------------------------------------------ protocol
    @property
    def shape(self) -> Shape2D:
        """(H, W) of the image."""
        return self._shape

    def __call__(self, request: SampleRequest) -> SampleBuffer:
        """Render the requested samples and return their per-pixel statistics (R, G, B) and features."""
        self._check_request(request)
        stats = PixelStatistics(request.counts.size, len(self.channels))
        feature_stats = {name: PixelStatistics(request.counts.size, len(FEATURES[name][1])) for name in self.features}
        nonfinite = 0
        for chunk in sample_chunks(request, self.batch_size):
            radiance, bad = self._trace(chunk)
            nonfinite += bad  # zeroed and counted in _trace; the buffer carries the count
            stats.add(chunk.per_pixel, radiance)
            if self.features:
                for name, values in self._trace_features(chunk, self.features).items():
                    feature_stats[name].add(chunk.per_pixel, values)
        buffer = stats.buffer(self._shape, self.channels, nonfinite)
        if not self.features:
            return buffer
        return dataclasses.replace(buffer, features={name: feature_stats[name].buffer(self._shape, FEATURES[name][1])
                                                     for name in self.features})

    def trace_samples(self, rows: np.ndarray, cols: np.ndarray, sample_index: np.ndarray) -> FloatArray:
        """(N, 3) float64 radiance of the given samples, one row per ``(row, col, sample index)``.

        The values depend on each sample's (seed, pixel, sample index) only, not on the other
        samples in the call. NaN/Inf radiance is replaced by 0 and counted in ``stats["nonfinite"]``.
        """
        rows, cols, sample_index = self._check_samples(rows, cols, sample_index)
        out = np.empty((rows.size, 3))
        for lo in range(0, rows.size, self.batch_size):
            hi = min(lo + self.batch_size, rows.size)
            out[lo:hi] = self._trace((rows[lo:hi], cols[lo:hi], sample_index[lo:hi]))[0].T  # to float64
        return out

    def render_features(self, request: SampleRequest,
                        names: Sequence[str] = tuple(FEATURES)) -> dict[str, SampleBuffer]:
        """Per-pixel statistics of first-hit features on the request's camera rays.

        Parameters
        ----------
        request
            The samples whose camera rays to use (the same rays :meth:`__call__` traces).
        names
            Features from :data:`FEATURES`: ``"albedo"`` (R, G, B), ``"normal"`` (X, Y, Z),
            ``"depth"`` (Z).

        Returns
        -------
        dict
            Feature name -> :class:`~awr_denoise.buffers.SampleBuffer` with the request's counts.
        """
        self._check_request(request)
        names = self._check_features(names)
        stats = {name: PixelStatistics(request.counts.size, len(FEATURES[name][1])) for name in names}
        for chunk in sample_chunks(request, self.batch_size):
            values = self._trace_features(chunk, names)
            for name in names:
                stats[name].add(chunk.per_pixel, values[name])
        return {name: stats[name].buffer(self._shape, FEATURES[name][1]) for name in names}

    def trace_features(self, rows: np.ndarray, cols: np.ndarray,
                       sample_index: np.ndarray) -> tuple[FloatArray, dict[str, FloatArray]]:
        """Radiance as :meth:`trace_samples` and ``{name: (N, channels)}`` values of :attr:`features`.

        This is the :class:`~awr_denoise.requests.FeatureTracer` method tiled rendering calls.
        """
        radiance = self.trace_samples(rows, cols, sample_index)
        if not self.features:
            return radiance, {}
        return radiance, self.trace_feature_values(rows, cols, sample_index, self.features)

    def trace_feature_values(self, rows: np.ndarray, cols: np.ndarray, sample_index: np.ndarray,
                             names: Sequence[str] = tuple(FEATURES)) -> dict[str, FloatArray]:
        """Feature name -> (N, C) float64 values of the given samples (see :meth:`render_features`)."""
        rows, cols, sample_index = self._check_samples(rows, cols, sample_index)
        names = self._check_features(names)
        parts = [self._trace_features((rows[lo:lo + self.batch_size], cols[lo:lo + self.batch_size],
                                       sample_index[lo:lo + self.batch_size]), names)
                 for lo in range(0, rows.size, self.batch_size)]
        if not parts:
            return {name: np.zeros((0, len(FEATURES[name][1]))) for name in names}
        return {name: np.concatenate([p[name] for p in parts], axis=1).T for name in names}

    def close(self) -> None:
        """Release the feature integrators; the renderer stays usable (Dr.Jit owns the kernels)."""
        self._feature_integrators.clear()

    def __repr__(self) -> str:
        integrator = getattr(self, "integrator", None)
        return (f"MitsubaRenderer({getattr(self, 'name', '?')!r}, shape={getattr(self, '_shape', None)}, "
                f"seed={self.seed}, variant={self.variant!r}, "
                f"integrator={integrator.class_name() if integrator is not None else None})")

    # ------------------------------------------------------------------ internals
    def _check_request(self, request: SampleRequest) -> None:
        if not isinstance(request, SampleRequest):
            raise TypeError(f"request: expected a SampleRequest, got {type(request).__name__}")
        if request.shape != self._shape:
            raise ValueError(f"request: shape {request.shape} does not match the scene's {self._shape}")
        if request.total and int((request.first_index + request.counts).max()) > _U32:
            raise ValueError("request: sample indices must stay below 2**32")

    def _check_samples(self, rows: Any, cols: Any, sample_index: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rows, cols, sample_index = (np.asarray(a, np.int64).ravel() for a in (rows, cols, sample_index))
        if not rows.size == cols.size == sample_index.size:
            raise ValueError(f"rows, cols, sample_index: lengths {rows.size}, {cols.size}, {sample_index.size} differ")
        h, w = self._shape
        if np.any((rows < 0) | (rows >= h) | (cols < 0) | (cols >= w)):
            raise ValueError(f"rows, cols: pixel coordinates outside the {h}x{w} image")
        if np.any((sample_index < 0) | (sample_index >= _U32)):
            raise ValueError("sample_index: must be in [0, 2**32)")
        return rows, cols, sample_index

    def _check_features(self, names: Sequence[str]) -> tuple[str, ...]:
        names = (names,) if isinstance(names, str) else tuple(names)
        unknown = [n for n in names if n not in FEATURES]
        if unknown or not names:
            raise ValueError(f"names: {unknown or 'none'} given; features are {', '.join(FEATURES)}")
        return tuple(dict.fromkeys(names))

    def _lanes(self, samples: Chunk | tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[Any, Any, Any]:
        """``(row, col, sample index)`` of every lane as Dr.Jit UInt32 arrays (not yet evaluated).

        A request's chunk is listed on the device: a binary search over the per-pixel ``ends``
        finds each lane's pixel, so only two per-pixel arrays are uploaded. An explicit list of
        samples is uploaded as it is.
        """
        mi, dr = self._mi, self._dr
        width = self._constant("width")
        if isinstance(samples, Chunk):
            ends, base = (mi.UInt32(aligned_u32(a)) for a in (samples.ends, samples.base))
            lane = dr.arange(mi.UInt32, samples.size)
            # The search range is the whole image whatever the chunk, so the kernel never changes.
            pixel = dr.binary_search(0, samples.ends.size - 1, lambda p: dr.gather(mi.UInt32, ends, p) <= lane)
            row = pixel // width
            return row, pixel - row * width, dr.gather(mi.UInt32, base, pixel) + lane
        return tuple(mi.UInt32(aligned_u32(a)) for a in samples)  # type: ignore[return-value]

    def _constant(self, name: str) -> Any:
        """A scalar of the scene as an opaque Dr.Jit value, made once: a kernel input, not a
        constant compiled into it, and no upload per call."""
        if name not in self._constants:
            mi, dr = self._mi, self._dr
            h, w = self._shape
            value = {"width": (mi.UInt32, w), "inv_width": (mi.Float, 1.0 / w), "inv_height": (mi.Float, 1.0 / h),
                     "shutter_open": (mi.Float, self._shutter_open),
                     "shutter_time": (mi.Float, self._shutter_time)}[name]
            self._constants[name] = dr.opaque(*value)
        return self._constants[name]

    def _seed_keys(self) -> tuple[Any, Any, Any, Any]:
        """The seed's four stream-key words as opaque Dr.Jit values (remade when the seed changes)."""
        if self._seed_cache[0] != self.seed:
            mi, dr = self._mi, self._dr
            self._seed_cache = (self.seed, tuple(dr.opaque(mi.UInt32, k) for k in _seed_words(self.seed)))
        return self._seed_cache[1]

    def _camera_rays(self, r: Any, c: Any, s: Any) -> tuple[Any, Any, Any]:
        """Seeded samplers and camera rays of the lanes, as Dr.Jit wavefronts (not yet evaluated)."""
        mi = self._mi
        pixel = r * self._constant("width") + c
        k0, k1, k2, k3 = self._seed_keys()
        sampler = self._sampler_class()
        # One stream per sample: TEA is a bijection of its 64-bit input, so distinct
        # (pixel, sample index) pairs get distinct stream selectors for a given seed.
        sampler.rng.seed(mi.sample_tea_64(s ^ k2, pixel ^ k3), mi.sample_tea_64(pixel ^ k0, s ^ k1))
        # The same draws, in the same order, as SamplingIntegrator::render_sample.
        offset = sampler.next_2d()
        position = mi.Point2f((mi.Float(c) + offset.x) * self._constant("inv_width"),
                              (mi.Float(r) + offset.y) * self._constant("inv_height"))
        aperture = sampler.next_2d() if self._needs_aperture else mi.Point2f(0.5, 0.5)
        shutter = self._constant("shutter_open")
        if self._shutter_time > 0:
            shutter = shutter + sampler.next_1d() * self._constant("shutter_time")
        ray, weight = self.sensor.sample_ray_differential(shutter, mi.Float(0.0), position, aperture)
        return sampler, ray, weight

    def _trace(self, samples: Chunk | tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[FloatArray, int]:
        """(3, N) float32 radiance (channel-major, as Dr.Jit stores it) and the non-finite count."""
        start = time.perf_counter()
        n = samples.size if isinstance(samples, Chunk) else samples[0].size
        if n == 0:
            return np.zeros((3, 0), np.float32), 0
        mi, dr = self._mi, self._dr
        with variant_scope(mi, self.variant):
            sampler, ray, weight = self._camera_rays(*self._lanes(samples))
            if self._python_ad:
                # Mitsuba's differentiable integrators (prb, ...): their primal pass, as their render() runs it.
                with dr.suspend_grad():
                    spectrum, _, _, _ = self.integrator.sample(
                        mode=dr.ADMode.Primal, scene=self.scene, sampler=sampler, ray=mi.Ray3f(ray),
                        depth=mi.UInt32(0), δL=None, δaovs=None, state_in=None, active=mi.Bool(True))
            else:
                spectrum, _, _ = self.integrator.sample(self.scene, sampler, ray, self.sensor.get_medium(), True)
            spectrum = spectrum * weight
            dr.eval(spectrum)
            radiance = np.array(spectrum)  # float32; statistics accumulate in float64
        bad = ~np.isfinite(radiance).all(axis=0)
        nonfinite = int(bad.sum())
        if nonfinite:
            radiance[:, bad] = 0.0
            logger.warning("%s: %d sample(s) with NaN/Inf radiance were replaced by 0", self.name, nonfinite)
        self.stats["nonfinite"] += nonfinite
        self.stats["samples"] += n
        self.stats["launches"] += 1
        self.stats["seconds"] += time.perf_counter() - start
        return radiance, nonfinite

    def _trace_features(self, samples: Chunk | tuple[np.ndarray, np.ndarray, np.ndarray],
                        names: tuple[str, ...]) -> dict[str, FloatArray]:
        """Feature name -> (C, N) float64 values (channel-major)."""
        mi, dr = self._mi, self._dr
        with variant_scope(mi, self.variant):
            integrator = self._feature_integrators.get(names)
            if integrator is None:
                aovs = ",".join(f"{name}:{FEATURES[name][0]}" for name in names)
                integrator = self._feature_integrators[names] = mi.load_dict({"type": "aov", "aovs": aovs})
            sampler, ray, _ = self._camera_rays(*self._lanes(samples))
            _, _, values = integrator.sample(self.scene, sampler, ray, self.sensor.get_medium(), True)
            # Mitsuba's depth is the distance along the ray; the project's is along the view axis.
            view_axis = self.sensor.world_transform() @ mi.Vector3f(0, 0, 1)
            cosine = dr.dot(ray.d, dr.normalize(view_axis))
            dr.eval(values, cosine)
            columns = [np.asarray(v, dtype=np.float64) for v in values]
            cosine = np.asarray(cosine, dtype=np.float64)
        out: dict[str, FloatArray] = {}
        for name in names:
            n = len(FEATURES[name][1])
            values = np.stack(columns[:n])
            columns = columns[n:]
            if name == "depth":
                values = values * cosine
            bad = ~np.isfinite(values)
            if bad.any():
                values[bad] = 0.0  # Mitsuba writes 0 for rays that miss; anything else non-finite too
                logger.warning("%s: %d non-finite %s value(s) were replaced by 0", self.name, int(bad.sum()), name)
            out[name] = values
        return out


_FILTER_PLUGINS = {"TentFilter": "tent", "GaussianFilter": "gaussian", "MitchellNetravaliFilter": "mitchell",
                   "CatmullRomFilter": "catmullrom", "LanczosSincFilter": "lanczos"}
"""Mitsuba's reconstruction filters by class, named as a scene names them (``<rfilter type="mitchell"/>``)."""


def _caller_level() -> int:
    """The ``stacklevel`` of the first caller outside awr_denoise, for the function calling this one: a warning
    points at the user's line, not at ``create_renderer``'s."""
    level, frame = 1, sys._getframe(1)
    while frame is not None and str(frame.f_globals.get("__name__", "")).split(".")[0] == "awr_denoise":
        frame, level = frame.f_back, level + 1
    return level


def _resized(scene: dict[str, Any], shape: Shape2D | None) -> dict[str, Any]:
    """A copy of a scene dict whose sensors' films have size ``shape`` (the dict itself is untouched)."""
    if shape is None:
        return scene
    h, w = shape
    out = dict(scene)
    found = False
    for key, value in scene.items():
        if isinstance(value, dict) and isinstance(value.get("film"), dict):
            film = dict(value["film"])
            if any(k.startswith("crop_") for k in film):
                raise ValueError(f"shape: the film of sensor {key!r} has a crop window; it cannot be resized")
            film["width"], film["height"] = int(w), int(h)
            out[key] = {**value, "film": film}
            found = True
    if not found:
        raise ValueError("shape: the scene dict has no sensor with a film dict to resize")
    return out


def _refuse_nonfinite(mi: Any, scene: Any, name: str) -> None:
    """Refuse a scene file holding a parameter Mitsuba took but cannot use: NaN or Inf (past float32 too). A
    sphere of radius NaN or 1e39, a fov or a lens aperture of NaN loaded without a word and rendered an
    image without the object or the view, exit 0 (a red-team pass). Read from the loaded scene's own
    parameters (``mi.traverse``): what Mitsuba uses, whichever file, include or default it came from."""
    parameters = mi.traverse(scene)
    for key in parameters.keys():
        value = parameters[key]
        value = getattr(value, "matrix", value)  # a transform: its matrix
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError, RuntimeError):
            continue  # not numbers (a bitmap's format, a flag)
        if array.size and not np.isfinite(array).all():
            node = parameters.properties[key][2]
            owner = node.class_name() if node is not None else "scene"
            raise InputFileError(f"{name}: {owner} parameter {key.rsplit('.', 1)[-1]!r} holds NaN or Inf (a value "
                                 "Mitsuba takes but cannot use: NaN, Inf or past float32 in the scene)")


def _parser_message(exc: BaseException, limit: int = 300) -> str:
    """Mitsuba's load error on one line: its innermost reason (an include loop nests one line per
    file), without the source location, at most ``limit`` characters."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    text = re.sub(r"\[[\w./-]+:\d+\]\s*", "", lines[-1] if lines else type(exc).__name__)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _load_file(mi: Any, variant: str, path: Path, shape: Shape2D | None, params: dict[str, Any]) -> Any:
    """Load a Mitsuba XML file, resizing every film to ``shape`` through Mitsuba's parser."""
    if shape is None:
        return mi.load_file(str(path), **params)
    # Files the scene names are found beside it, as mi.load_file arranges (beside a link, not
    # beside its target: the folder as named).
    previous = mi.file_resolver()
    resolver = mi.FileResolver(previous)
    resolver.prepend(str(path.absolute().parent))
    mi.set_file_resolver(resolver)
    try:
        config = mi.parser.ParserConfig(variant)
        state = mi.parser.parse_file(config, str(path), **params)
        mi.parser.transform_all(config, state)
        h, w = shape
        found = False
        for node in state.nodes:
            if node.type == mi.ObjectType.Film:
                props = node.props
                if any(str(k).startswith("crop_") for k in props.keys()):
                    raise ValueError(f"shape: the film in {path} has a crop window; it cannot be resized")
                props["width"], props["height"] = int(w), int(h)
                node.props = props
                found = True
        if not found:
            raise ValueError(f"shape: {path} declares no film to resize")
        return mi.parser.instantiate(config, state)
    finally:
        mi.set_file_resolver(previous)


def list_scenes() -> list[str]:
    """Names of the bundled Mitsuba scenes (:mod:`awr_denoise.adapters.mitsuba_scenes`)."""
    return list(ALL_SCENES)


def list_features() -> list[str]:
    """The features ``create_renderer(..., features=...)`` renders (:data:`FEATURES`)."""
    return list(FEATURES)


def create_renderer(scene: Any, *, shape: Shape2D | None = None, seed: int = 0, **options: Any) -> MitsubaRenderer:
    """Renderer factory for the registry (entry point ``mitsuba`` of ``awr_denoise.renderers``).

    Parameters
    ----------
    scene
        Mitsuba XML path, scene dict, loaded ``mitsuba.Scene`` or bundled scene name.
    shape, seed
        (H, W) of the image (default the film's) and the render seed.
    **options
        Further keyword arguments of :class:`MitsubaRenderer` (``variant``, ``sensor``,
        ``batch_size``, ``params``).

    Examples
    --------
    >>> from awr_denoise import SampleRequest
    >>> from awr_denoise.adapters.mitsuba import create_renderer
    >>> renderer = create_renderer("cornell_box", shape=(16, 16), seed=3)  # doctest: +SKIP
    >>> renderer(SampleRequest.uniform((16, 16), 2)).total_samples  # doctest: +SKIP
    512
    """
    return MitsubaRenderer(scene, shape=shape, seed=seed, **options)
