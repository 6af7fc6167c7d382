"""The wavefront path tracer: a :class:`~awr_denoise.requests.Renderer` on top of embreex.

:class:`PathTracer` takes a :class:`~awr_denoise.requests.SampleRequest`, traces exactly the
requested samples (``first_index .. first_index + counts - 1`` of each pixel) and returns their
per-pixel statistics as a :class:`~awr_denoise.buffers.SampleBuffer` (channels R, G, B): the
renderer side of the paper's loop (Overbeck et al. 2009, section 1; docs/concepts.md, "Round").

Structure (pbrt-v4 vocabulary, wavefront over arrays): the camera turns ``(p_film, p_lens,
time)`` into rays; every bounce is one batched ``intersect`` over all live paths, then shading
by material with masks, next-event estimation to area lights, the environment and delta lights
with one batched ``occluded`` query, and BSDF sampling for the next bounce. Multiple importance
sampling (power heuristic, Veach 1997) combines light and BSDF sampling wherever both happen;
at the last vertex light sampling takes full weight.

Every random number is addressed by (seed, pixel, sample index, dimension) (see
:mod:`~awr_denoise.tracer.sampler`), so results do not depend on how samples are grouped into
requests, batches or threads. Batches run on a thread pool: embreex releases the GIL while it
traces and numpy releases it in large array operations.
"""

from __future__ import annotations

import dataclasses
import logging
import time as _time
import multiprocessing
import os
from concurrent.futures import Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from .._progress import tqdm

from .._workers import exit_with_parent
from ..buffers import SampleBuffer
from ..features import FEATURE_CHANNELS, feature_names
from ..parts import render_in_parts
from ..requests import MAX_PART_SAMPLES, SampleRequest
from .accel import Accelerator
from .features import FeatureRecorder
from .lights import DirectionalLight, PointLight
from .meshes import coordinate_frame, dot, normalize
from .sampler import SAMPLER_NAMES, make_sampler
from .scene import Scene, dimension_names, load_scene

__all__ = ["PathTracer", "render", "DEFAULT_BATCH_SIZE", "WORKER_KINDS"]

logger = logging.getLogger(__name__)

_MIN_THREAD_BATCH = 2048

WORKER_KINDS = ("threads", "processes")
"""Valid values of ``PathTracer(workers=...)``."""

# The tracer of a worker process (``workers="processes"``), built once by _start_worker.
_worker_tracer: PathTracer | None = None


def _start_worker(scene: Scene, seed: int, sampler: str, max_depth: int, batch_size: int,
                  features: tuple[str, ...], parent: int) -> None:
    global _worker_tracer
    exit_with_parent(parent)  # a parent killed without closing the pool left its workers for good
    _worker_tracer = PathTracer(scene, seed=seed, sampler=sampler, max_depth=max_depth, threads=1,
                                batch_size=batch_size, features=features)


def _worker_trace(rows: np.ndarray, cols: np.ndarray, sample_index: np.ndarray
                  ) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, int], set[str]]:
    assert _worker_tracer is not None
    values, features, counts = _worker_tracer._trace_batch(rows, cols, sample_index)
    return values, features, counts, set(_worker_tracer.dimensions_drawn)

DEFAULT_BATCH_SIZE = 1 << 16
"""Samples traced together in one wavefront (per thread)."""


def _power_heuristic(pdf_a: np.ndarray, pdf_b: np.ndarray) -> np.ndarray:
    a2, b2 = pdf_a * pdf_a, pdf_b * pdf_b
    total = a2 + b2
    return np.where(total > 0, a2 / np.where(total > 0, total, 1.0), 0.0)


def _dimension_groups(names: tuple[str, ...]) -> dict[str, tuple[int, ...]]:
    # Pairs of dimensions that form one 2D sample (for the Sobol' sampler's padding).
    groups: dict[str, tuple[int, ...]] = {}
    for i, name in enumerate(names):
        stem = name.rsplit("_", 1)[0]
        partners = tuple(j for j, other in enumerate(names) if other.rsplit("_", 1)[0] == stem)
        groups[name] = partners if len(partners) == 2 else (i,)
    return groups


class PathTracer:
    """Batched path tracer implementing the ``Renderer`` and ``SampleTracer`` protocols.

    Parameters
    ----------
    scene
        A :class:`Scene`, a bundled scene name, a JSON path or a spec dict.
    seed
        Render seed (independent renders for different seeds).
    sampler
        ``"independent"`` (hashed uniform numbers) or ``"sobol"`` (Owen-scrambled padded 2D
        Sobol'); see :mod:`~awr_denoise.tracer.sampler`.
    max_depth
        Number of diffuse/glossy bounces after the first hit (0 = direct lighting only);
        ``None`` uses the scene's ``integrator.max_depth``.
    threads
        Number of workers that trace batches concurrently.
    workers
        ``"threads"`` (default): a thread pool in this process; embreex and large numpy
        operations release the GIL, the Python glue between numpy calls does not.
        ``"processes"``: a pool of spawned processes, each with its own copy of the scene and
        BVH (started on first use, about a second each); it scales past the GIL. Scripts need
        the ``if __name__ == "__main__":`` guard (spawned workers re-import the main module).
        Sample values are bit-identical either way.
    progress
        Show a tqdm progress bar over batches.
    batch_size
        Samples per wavefront batch.
    features
        Features to render with the radiance, any of ``("albedo", "normal", "depth")`` (or
        ``"all"``); the returned buffers carry them (:attr:`SampleBuffer.features`). Which hit
        each describes: :mod:`awr_denoise.tracer.features`. They draw no random numbers, so the
        radiance samples are the same with and without them.

    Attributes
    ----------
    shape
        (H, W) of the image.
    dimensions
        Names of the random dimensions drawn per sample (only the scene's effects); their count
        is :attr:`dimension`.
    dimensions_drawn
        Names of the dimensions actually drawn so far (a check on :attr:`dimensions`).
    stats
        Running totals: ``samples``, ``rays`` (all queries), ``camera_rays``, ``bounce_rays``,
        ``shadow_rays``, ``nonfinite`` (samples whose radiance was NaN/Inf and was replaced by
        0) and ``seconds``.
    channels
        ``("R", "G", "B")``: linear radiance.
    """

    channels: tuple[str, ...] = ("R", "G", "B")
    max_part_samples: int = MAX_PART_SAMPLES
    """Most samples traced at once (:meth:`SampleRequest.pieces`): a larger request is traced in parts,
    so its memory stays near 0.5 GB whatever its size (a uniform 1080p render at 128 spp needed 32 GB)."""

    def __init__(self, scene: Scene | str | Path | dict[str, Any], *, seed: int = 0,
                 sampler: str = "independent", max_depth: int | None = None, threads: int = 2,
                 progress: bool = False, batch_size: int = DEFAULT_BATCH_SIZE, workers: str = "threads",
                 features: tuple[str, ...] | str | None = None) -> None:
        self.scene = load_scene(scene)
        self.features = feature_names(features)
        if sampler not in SAMPLER_NAMES:
            raise ValueError(f"sampler: {sampler!r} is not one of {', '.join(SAMPLER_NAMES)}")
        if int(seed) < 0:
            raise ValueError(f"seed: {seed} must be >= 0")
        if max_depth is not None and int(max_depth) < 0:
            raise ValueError(f"max_depth: {max_depth} must be >= 0 or None")
        if int(threads) < 1:
            raise ValueError(f"threads: {threads} must be >= 1")
        if workers not in WORKER_KINDS:
            raise ValueError(f"workers: {workers!r} is not one of {', '.join(WORKER_KINDS)}")
        self.workers = workers
        if int(batch_size) < 1:
            raise ValueError(f"batch_size: {batch_size} must be >= 1")
        self.seed = int(seed)
        self.sampler_name = sampler
        self.sampler = make_sampler(sampler, self.seed)
        self.max_depth = self.scene.max_depth if max_depth is None else int(max_depth)
        self.threads = int(threads)
        self.progress = bool(progress)
        self.batch_size = int(batch_size)
        self.dimensions = dimension_names(self.scene, self.max_depth)
        self._dimension_index = {name: i for i, name in enumerate(self.dimensions)}
        self._groups = _dimension_groups(self.dimensions)
        self.dimensions_drawn: set[str] = set()
        self.accelerator = Accelerator(self.scene)
        self.area_lights = self.scene.area_lights
        self.environment = self.scene.environment
        has_area, has_env = self.area_lights is not None, self.environment is not None
        # Light-type selection: half the light samples to each when a scene has both.
        self.p_select_environment = 0.5 if (has_area and has_env) else (1.0 if has_env else 0.0)
        self.stats: dict[str, float] = {"samples": 0, "rays": 0, "camera_rays": 0, "bounce_rays": 0,
                                        "shadow_rays": 0, "nonfinite": 0, "seconds": 0.0}
        self._pool: Executor | None = None
        if self.threads > 1 and workers == "threads":
            self._pool = ThreadPoolExecutor(max_workers=self.threads)

    # ------------------------------------------------------------------ public
    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the image."""
        return self.scene.shape

    @property
    def dimension(self) -> int:
        """Number of random dimensions per sample, ``len(dimensions)`` (the integrand dimension)."""
        return len(self.dimensions)

    def __call__(self, request: SampleRequest) -> SampleBuffer:
        """Trace the requested samples and return their per-pixel statistics (R, G, B)."""
        if not isinstance(request, SampleRequest):
            raise TypeError(f"request: expected a SampleRequest, got {type(request).__name__}")
        if request.shape != self.shape:
            raise ValueError(f"request: shape {request.shape} does not match the scene's {self.shape}")
        # In parts of at most max_part_samples: every sample of a part is held at once (about 120 bytes each).
        return render_in_parts(request, self._render_part, self.max_part_samples)

    def _render_part(self, first_row: int, part: SampleRequest) -> SampleBuffer:
        """The statistics of ``part``, whose row 0 is the image's ``first_row``."""
        rows, cols, sample_index = part.pixel_list()
        radiance, features, nonfinite = self._trace(rows + first_row, cols, sample_index)
        # Non-finite samples were already zeroed and counted in _trace; the buffer carries the count.
        buffer = SampleBuffer.from_samples(rows * part.shape[1] + cols, radiance, part.shape, channels=self.channels,
                                           features=features)
        return dataclasses.replace(buffer, nonfinite=nonfinite)

    def trace_samples(self, rows: np.ndarray, cols: np.ndarray, sample_index: np.ndarray) -> np.ndarray:
        """(N, 3) float64 radiance of the given samples (one row per (row, col, sample index)).

        NaN/Inf radiance is replaced by 0, counted in ``stats["nonfinite"]`` and logged.
        """
        return self._trace(rows, cols, sample_index)[0]

    def trace_features(self, rows: np.ndarray, cols: np.ndarray,
                       sample_index: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Radiance as :meth:`trace_samples` and ``{name: (N, channels)}`` values of :attr:`features`."""
        radiance, features, _ = self._trace(rows, cols, sample_index)
        return radiance, features

    def _trace(self, rows: np.ndarray, cols: np.ndarray,
               sample_index: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray], int]:
        start = _time.perf_counter()
        rows, cols, sample_index = (np.asarray(a, np.int64).ravel() for a in (rows, cols, sample_index))
        n = len(rows)
        h, w = self.shape
        if np.any((rows < 0) | (rows >= h) | (cols < 0) | (cols >= w)):
            raise ValueError(f"rows, cols: pixel coordinates outside the {h}x{w} image")
        radiance = np.zeros((n, 3))
        features = {name: np.zeros((n, len(FEATURE_CHANNELS[name]))) for name in self.features}
        # At least one batch per thread (down to a floor where thread overhead would dominate).
        batch = max(min(self.batch_size, -(-n // self.threads)), min(self.batch_size, _MIN_THREAD_BATCH))
        bounds = [(s, min(s + batch, n)) for s in range(0, n, batch)]

        def run(bound: tuple[int, int]) -> tuple[int, int, dict[str, int]]:
            lo, hi = bound
            values, batch_features, counts = self._trace_batch(rows[lo:hi], cols[lo:hi], sample_index[lo:hi])
            radiance[lo:hi] = values
            for name, rows_of in batch_features.items():
                features[name][lo:hi] = rows_of
            return lo, hi, counts

        if self.workers == "processes" and self.threads > 1 and len(bounds) > 1:
            if self._pool is None:
                self._pool = ProcessPoolExecutor(
                    max_workers=self.threads, mp_context=multiprocessing.get_context("spawn"),
                    initializer=_start_worker,
                    initargs=(self.scene, self.seed, self.sampler_name, self.max_depth, self.batch_size,
                              self.features, os.getpid()))
            futures = [self._pool.submit(_worker_trace, rows[lo:hi], cols[lo:hi], sample_index[lo:hi])
                       for lo, hi in bounds]

            def collect(item: tuple[tuple[int, int], Future]) -> tuple[int, int, dict[str, int]]:
                (lo, hi), future = item
                values, batch_features, counts, drawn = future.result()
                radiance[lo:hi] = values
                for name, rows_of in batch_features.items():
                    features[name][lo:hi] = rows_of
                self.dimensions_drawn.update(drawn)
                return lo, hi, counts

            results = map(collect, zip(bounds, futures))
        elif self._pool is not None and len(bounds) > 1:
            results = self._pool.map(run, bounds)
        else:
            results = map(run, bounds)
        if self.progress:
            results = tqdm(results, total=len(bounds), desc=f"{self.scene.name}", unit="batch")
        for _, _, counts in results:
            for key, value in counts.items():
                self.stats[key] += value
        bad = ~np.isfinite(radiance).all(axis=1)
        nonfinite = int(bad.sum())
        if nonfinite:
            radiance[bad] = 0.0
            logger.warning("%s: %d sample(s) with NaN/Inf radiance were replaced by 0", self.scene.name, nonfinite)
        self.stats["nonfinite"] += nonfinite
        self.stats["samples"] += n
        self.stats["seconds"] += _time.perf_counter() - start
        return radiance, features, nonfinite

    def close(self) -> None:
        """Shut the workers down."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def __del__(self) -> None:
        pool = getattr(self, "_pool", None)
        if pool is not None:
            pool.shutdown(wait=False)

    def __repr__(self) -> str:
        return (f"PathTracer({self.scene.name!r}, sampler={self.sampler_name!r}, seed={self.seed}, "
                f"max_depth={self.max_depth}, dimensions={len(self.dimensions)}"
                + (f", features={self.features})" if self.features else ")"))

    # ------------------------------------------------------------------ internals
    def _draw(self, name: str, key: np.ndarray, sample_index: np.ndarray) -> np.ndarray:
        self.dimensions_drawn.add(name)
        index = self._dimension_index[name]
        return self.sampler.get(key, index, sample_index=sample_index, group=self._groups[name])

    def _trace_batch(self, rows: np.ndarray, cols: np.ndarray,
                     sample_index: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, int]]:
        with np.errstate(all="ignore"):  # non-finite values are caught and counted per sample
            return self._li(rows, cols, sample_index)

    def _record_hits(self, record: FeatureRecorder, paths: np.ndarray, points: np.ndarray, normals: np.ndarray,
                     p_object: np.ndarray, obj: np.ndarray, emission: np.ndarray, *, first: bool) -> None:
        """Features of a bounce's surface hits: depth of camera hits, albedo and normal of open paths."""
        if first:
            record.camera_hits(paths, points)
        open_ = record.open[paths]
        if not open_.any():
            return
        material_index = np.where(np.any(emission > 0, axis=1), -1, self.accelerator.object_material[obj])
        reflectance = np.zeros((len(paths), 3))   # emitters reflect nothing here
        delta = np.zeros(len(paths), bool)
        for m in np.unique(material_index[open_]):
            if m < 0:
                continue
            at = open_ & (material_index == m)
            material = self.scene.materials[m]
            reflectance[at] = material.reflectance(p_object[at])
            delta[at] = material.is_specular
        record.surfaces(paths, normals, reflectance, delta)

    def _li(self, rows: np.ndarray, cols: np.ndarray,
            sample_index: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, int]]:
        """Radiance of a wavefront of camera samples, their features and the rays traced for it.

        One function on purpose: the wavefront's state (throughput, specular depth, the
        previous bounce's pdf for MIS, the active mask and its index map) changes together at
        every bounce, and the arrays shrink as paths end; split into helpers it would travel
        through a dozen parameters and return values per bounce.
        """
        scene, camera, accel = self.scene, self.scene.camera, self.accelerator
        n = len(rows)
        counts = {"rays": 0, "camera_rays": 0, "bounce_rays": 0, "shadow_rays": 0}
        pixel = rows * scene.width + cols
        key = self.sampler.start(pixel, sample_index)
        p_film = np.stack([cols + self._draw("pixel_x", key, sample_index),
                           rows + self._draw("pixel_y", key, sample_index)], axis=-1)
        p_lens = None
        if camera.has_lens:
            p_lens = np.stack([self._draw("lens_u", key, sample_index),
                               self._draw("lens_v", key, sample_index)], axis=-1)
        if scene.has_motion:
            time = camera.time(self._draw("time", key, sample_index))
        else:
            time = np.full(n, camera.shutter_open)
        if scene.has_sampled_lights:
            light_u = self._draw("light_u", key, sample_index)
            light_v = self._draw("light_v", key, sample_index)
        o, d = camera.generate_rays(p_film, p_lens)

        radiance = np.zeros((n, 3))
        path = np.arange(n)                   # which sample each live ray belongs to
        beta = np.ones((n, 3))                # path throughput
        specular = np.ones(n, bool)           # previous vertex was the camera or a mirror
        prev_pdf = np.zeros(n)                # BSDF pdf of the previous bounce (for MIS)
        depth = np.zeros(n, np.int64)         # diffuse/glossy vertices so far
        specular_depth = np.zeros(n, np.int64)
        ray_kind = "camera_rays"
        eps = accel.epsilon
        record = None
        if self.features:
            record = FeatureRecorder(n, self.features, camera.look_from, camera.world_from_camera[:, 2])

        while len(path):
            t_ray = time[path]
            hits = accel.intersect(o, d, t_ray)
            counts["rays"] += len(path) * accel.scene_count
            counts[ray_kind] += len(path)
            first_bounce = ray_kind == "camera_rays"
            ray_kind = "bounce_rays"

            # --- rays that escape: environment emission, MIS-weighted after a BSDF bounce
            miss = ~hits.valid
            if record is not None:
                record.misses(path[miss])
            if self.environment is not None and miss.any():
                wm = d[miss]
                le = self.environment.evaluate(wm)
                pdf_light = self.p_select_environment * self.environment.pdf(wm)
                weight = np.where(specular[miss], 1.0, _power_heuristic(prev_pdf[miss], pdf_light))
                radiance[path[miss]] += beta[miss] * le * weight[:, None]

            # --- surface hits
            hit = hits.valid
            if not hit.any():
                break
            p, n_geo, n_sh, p_object = accel.surface(hits, t_ray)
            obj = hits.object_index[hit]
            wo = -d[hit]
            hp, hbeta, hspec, hprev, hdepth, hsdepth = (path[hit], beta[hit], specular[hit], prev_pdf[hit],
                                                       depth[hit], specular_depth[hit])
            h_time = t_ray[hit]
            to_hit = p - o[hit]
            distance = np.sqrt(dot(to_hit, to_hit))
            # Emission (one-sided, on the side of the geometric normal).
            emission = accel.object_emission[obj]
            cos_light = dot(n_geo, wo)
            emissive = np.any(emission > 0, axis=1) & (cos_light > 0)
            if emissive.any():
                w_emit = np.ones(len(obj))
                if self.area_lights is not None:
                    pdf_light = ((1.0 - self.p_select_environment) * self.area_lights.pdf_area
                                 * distance ** 2 / np.where(cos_light > 0, cos_light, 1.0))
                    w_emit = np.where(hspec, 1.0, _power_heuristic(hprev, pdf_light))
                contribution = hbeta * emission * w_emit[:, None]
                radiance[hp[emissive]] += contribution[emissive]
            # Two-sided surfaces: shade on the side the ray came from.
            flip = dot(n_geo, wo) < 0
            n_geo[flip] *= -1.0
            n_sh[flip] *= -1.0
            # A shading normal facing away from the viewer would make the surface black.
            bad_shading = dot(n_sh, wo) <= 0
            n_sh[bad_shading] = n_geo[bad_shading]
            if record is not None:
                self._record_hits(record, hp, p, n_sh, p_object, obj, emission, first=first_bounce)
            # Emitters reflect nothing: their paths end here (material -1 sorts first, skipped).
            material_index = np.where(np.any(emission > 0, axis=1), -1, accel.object_material[obj])
            # Sort hits by material once, so each material below works on contiguous slices
            # instead of masking every array once per material.
            order = np.argsort(material_index, kind="stable")
            material_index = material_index[order]
            p, n_geo, n_sh, p_object, wo = p[order], n_geo[order], n_sh[order], p_object[order], wo[order]
            hp, hbeta, hdepth, hsdepth, h_time = hp[order], hbeta[order], hdepth[order], hsdepth[order], h_time[order]
            materials_present = np.unique(material_index)
            starts = np.searchsorted(material_index, materials_present, side="left")
            ends = np.searchsorted(material_index, materials_present, side="right")

            shadow_o, shadow_d, shadow_dist, shadow_time, shadow_target, shadow_value = [], [], [], [], [], []
            next_o, next_d, next_path, next_beta, next_spec, next_pdf, next_depth, next_sdepth = ([] for _ in range(8))

            for m, lo, hi in zip(materials_present, starts, ends):
                if m < 0:
                    continue
                material = scene.materials[m]
                sel = slice(lo, hi)
                s_p, s_ng, s_ns, s_wo = p[sel], n_geo[sel], n_sh[sel], wo[sel]
                s_path, s_beta, s_depth, s_sdepth = hp[sel], hbeta[sel], hdepth[sel], hsdepth[sel]
                s_time = h_time[sel]
                origin = s_p + eps * s_ng
                if material.is_specular:
                    wi = 2.0 * dot(s_wo, s_ns)[:, None] * s_ns - s_wo
                    keep = (dot(wi, s_ng) > 0) & (s_sdepth < scene.max_specular_depth)
                    next_o.append(origin[keep])
                    next_d.append(normalize(wi[keep]))
                    next_path.append(s_path[keep])
                    next_beta.append(s_beta[keep] * material.specular)
                    next_spec.append(np.ones(int(keep.sum()), bool))
                    next_pdf.append(np.zeros(int(keep.sum())))
                    next_depth.append(s_depth[keep])
                    next_sdepth.append(s_sdepth[keep] + 1)
                    continue
                tangent, bitangent = coordinate_frame(s_ns)

                def to_local(v: np.ndarray) -> np.ndarray:
                    return np.stack([dot(v, tangent), dot(v, bitangent), dot(v, s_ns)], axis=-1)

                wo_local = to_local(s_wo)
                kd = material.diffuse_albedo(p_object[sel])
                continues = s_depth < self.max_depth

                # Next-event estimation: delta lights (no random numbers).
                for light in scene.delta_lights:
                    if isinstance(light, PointLight):
                        to_light = light.position - s_p
                        dist = np.sqrt(dot(to_light, to_light))
                        wi = to_light / dist[:, None]
                        li = light.intensity / (dist * dist)[:, None]
                    else:
                        assert isinstance(light, DirectionalLight)
                        wi = np.broadcast_to(-light.direction, s_p.shape)
                        dist = np.full(len(s_p), np.inf)
                        li = np.broadcast_to(light.irradiance, s_p.shape)
                    f = material.evaluate(wo_local, to_local(wi), kd)
                    cos_i = np.abs(dot(wi, s_ns))
                    value = s_beta * f * li * cos_i[:, None]
                    ok = (dot(wi, s_ng) > 0) & np.any(value > 0, axis=1)
                    shadow_o.append(origin[ok])
                    shadow_d.append(wi[ok])
                    shadow_dist.append(dist[ok] - 2 * eps)
                    shadow_time.append(s_time[ok])
                    shadow_target.append(s_path[ok])
                    shadow_value.append(value[ok])

                # Next-event estimation: one area-light or environment sample (light_u, light_v).
                if scene.has_sampled_lights:
                    lu, lv = light_u[s_path], light_v[s_path]
                    wi = np.zeros_like(s_p)
                    le = np.zeros_like(s_p)
                    pdf_light = np.zeros(len(s_p))
                    dist = np.full(len(s_p), np.inf)
                    use_env = lu < self.p_select_environment
                    if self.environment is not None and use_env.any():
                        u_env = lu[use_env] / self.p_select_environment
                        w_env, le_env, pdf_env = self.environment.sample(u_env, lv[use_env])
                        wi[use_env], le[use_env] = w_env, le_env
                        pdf_light[use_env] = self.p_select_environment * pdf_env
                    use_area = ~use_env
                    if self.area_lights is not None and use_area.any():
                        p_area = 1.0 - self.p_select_environment
                        u_area = (lu[use_area] - self.p_select_environment) / p_area
                        p_light, n_light, le_area = self.area_lights.sample(u_area, lv[use_area])
                        to_light = p_light - s_p[use_area]
                        dist_area = np.sqrt(dot(to_light, to_light))
                        w_area = to_light / np.where(dist_area > 0, dist_area, 1.0)[:, None]
                        cos_l = -dot(n_light, w_area)
                        pdf_area = p_area * self.area_lights.pdf_area * dist_area ** 2 / np.where(cos_l > 0, cos_l, 1.0)
                        wi[use_area] = w_area
                        le[use_area] = np.where((cos_l > 0)[:, None], le_area, 0.0)
                        pdf_light[use_area] = np.where(cos_l > 0, pdf_area, 0.0)
                        dist[use_area] = dist_area * (1.0 - 1e-5) - 2 * eps
                    wi_local = to_local(wi)
                    f = material.evaluate(wo_local, wi_local, kd)
                    pdf_bsdf = material.pdf(wo_local, wi_local, kd)
                    weight = np.where(continues, _power_heuristic(pdf_light, pdf_bsdf), 1.0)
                    cos_i = np.abs(wi_local[:, 2])
                    ratio = np.where(pdf_light > 0, weight * cos_i / np.where(pdf_light > 0, pdf_light, 1.0), 0.0)
                    value = s_beta * f * le * ratio[:, None]
                    ok = (dot(wi, s_ng) > 0) & np.any(value != 0, axis=1)
                    shadow_o.append(origin[ok])
                    shadow_d.append(wi[ok])
                    shadow_dist.append(dist[ok])
                    shadow_time.append(s_time[ok])
                    shadow_target.append(s_path[ok])
                    shadow_value.append(value[ok])

                # BSDF sampling for the next bounce (bounce{k}_u, bounce{k}_v).
                for k in np.unique(s_depth[continues]):
                    at_k = continues & (s_depth == k)
                    key_k, index_k = key[s_path[at_k]], sample_index[s_path[at_k]]
                    u = self._draw(f"bounce{k}_u", key_k, index_k)
                    v = self._draw(f"bounce{k}_v", key_k, index_k)
                    wi_local, f, pdf = material.sample(wo_local[at_k], u, v, kd[at_k])
                    wi = (wi_local[:, :1] * tangent[at_k] + wi_local[:, 1:2] * bitangent[at_k]
                          + wi_local[:, 2:] * s_ns[at_k])
                    throughput = f * (np.abs(wi_local[:, 2]) / np.where(pdf > 0, pdf, 1.0))[:, None]
                    keep = (pdf > 0) & (dot(wi, s_ng[at_k]) > 0) & np.any(throughput > 0, axis=1)
                    next_o.append(origin[at_k][keep])
                    next_d.append(normalize(wi[keep]))
                    next_path.append(s_path[at_k][keep])
                    next_beta.append((s_beta[at_k] * throughput)[keep])
                    next_spec.append(np.zeros(int(keep.sum()), bool))
                    next_pdf.append(pdf[keep])
                    next_depth.append(s_depth[at_k][keep] + 1)
                    next_sdepth.append(s_sdepth[at_k][keep])

            # One batched shadow query for every light sample of this bounce.
            if shadow_o:
                so = np.concatenate(shadow_o)
                if len(so):
                    blocked = accel.occluded(so, np.concatenate(shadow_d), np.concatenate(shadow_dist),
                                             np.concatenate(shadow_time))
                    counts["rays"] += len(so) * accel.scene_count
                    counts["shadow_rays"] += len(so)
                    visible = ~blocked
                    target = np.concatenate(shadow_target)[visible]
                    value = np.concatenate(shadow_value)[visible]
                    for c in range(3):  # duplicate targets (several lights) must all add up
                        radiance[:, c] += np.bincount(target, weights=value[:, c], minlength=n)

            if not next_path:
                break
            path = np.concatenate(next_path)
            o = np.concatenate(next_o)
            d = np.concatenate(next_d)
            beta = np.concatenate(next_beta)
            specular = np.concatenate(next_spec)
            prev_pdf = np.concatenate(next_pdf)
            depth = np.concatenate(next_depth)
            specular_depth = np.concatenate(next_sdepth)
        return radiance, {} if record is None else record.values(), counts


def render(scene: Scene | str | Path | dict[str, Any], *, spp: int, seed: int = 0, sampler: str = "independent",
           max_depth: int | None = None, threads: int = 2, progress: bool = False,
           first_index: int = 0) -> SampleBuffer:
    """Render ``spp`` samples at every pixel (a uniform request) and return their statistics."""
    if int(spp) < 1:
        raise ValueError(f"spp: {spp} must be >= 1")
    tracer = PathTracer(scene, seed=seed, sampler=sampler, max_depth=max_depth, threads=threads, progress=progress)
    try:
        return tracer(SampleRequest.uniform(tracer.shape, int(spp), first_index=first_index))
    finally:
        tracer.close()



def create_renderer(scene: Scene | str | Path | dict[str, Any], *, shape: tuple[int, int] | None = None,
                    seed: int = 0, **options: Any) -> PathTracer:
    """Renderer factory of the registry (:mod:`awr_denoise.renderers`): a :class:`PathTracer`.

    Parameters
    ----------
    scene
        A bundled scene name, a JSON scene file, a spec dict or a :class:`Scene`.
    shape
        (H, W) to render at; ``None`` (or 0 on either side) keeps the scene's own.
    seed
        Render seed.
    **options
        Keyword arguments of :class:`PathTracer` (``sampler``, ``max_depth``, ``threads``,
        ``batch_size``, ``workers``, ``progress``).
    """
    height, width = shape if shape is not None else (None, None)
    return PathTracer(load_scene(scene, width=width or None, height=height or None), seed=seed, **options)
