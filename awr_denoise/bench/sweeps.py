"""Sweeps of the library's settings on one path-traced scene: ``c_s`` and domain, and the other defaults.

Each setting's relMSE is a mean over several render seeds, so a difference between settings is
not one seed's luck.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from .._typing import FloatArray
from ..buffers import SampleBuffer
from ..metrics import relmse
from ..noise_gain import DEFAULT_NOISE_MODEL
from ..reconstruct import reconstruct
from ..sampling import DEFAULT_AWR_INITIAL_SPP, DEFAULT_ROUND_GROWTH, AdaptiveSampler
from ..wavelets import default_levels, max_levels
from .config import DOMAINS, BenchmarkConfig
from .measure import run_progressive
from .rendering import make_tracer, render_uniform

__all__ = ["cs_sweep", "defaults_sweep"]


def cs_sweep(scene: Any, reference: FloatArray, weight: FloatArray, floor: float, config: BenchmarkConfig,
             seed0: SampleBuffer | None) -> tuple[list[dict[str, Any]], dict[str, FloatArray]]:
    """relMSE, squared bias and variance against ``c_s`` for every domain, over several seeds.

    Parameters
    ----------
    scene
        The scene.
    reference
        Its reference image.
    weight
        relMSE weight per pixel and channel, ``1 / (reference^2 + eps)``.
    floor
        The reference's noise floor, removed from the squared bias.
    config
        ``sweep_spp``, ``sweep_seeds``, ``c_s_values``, ``seed`` and ``threads`` are used.
    seed0
        The uniform buffer at ``sweep_spp`` already rendered with seed 0, if any (reused).

    Returns
    -------
    tuple
        The rows (one for the plain mean, one per domain and ``c_s``), and the first seed's
        images by label (``"mean"``, ``"<domain> c_s=<c_s>"``) for the crops figure.
    """
    buffers = []
    for s in range(config.sweep_seeds):
        if s == 0 and seed0 is not None and config.seed == 0:
            buffers.append(seed0)
        else:
            buffers.append(render_uniform(scene, config.sweep_spp, config.seed + s, config.threads))
    rows = []
    mean_err = [relmse(b.mean, reference) for b in buffers]
    rows.append({"domain": "mean", "c_s": 0.0, "spp": config.sweep_spp, "relmse": float(np.mean(mean_err))})
    outputs: dict[tuple[str, float], FloatArray] = {}
    for dname, dom in DOMAINS.items():
        for c_s in config.c_s_values:
            outs = np.stack([reconstruct(b, c_s=float(c_s), domain=dom) for b in buffers])
            outputs[(dname, float(c_s))] = outs[0]
            errs = [relmse(o, reference) for o in outs]
            n = len(buffers)
            variance = float(np.mean(np.var(outs, axis=0, ddof=1) * weight[None])) if n > 1 else float("nan")
            bias_raw = float(np.mean((outs.mean(axis=0) - reference) ** 2 * weight))
            bias2 = bias_raw - (variance / n if n > 1 else 0.0) - floor
            rows.append({"domain": dname, "c_s": float(c_s), "spp": config.sweep_spp, "relmse": float(np.mean(errs)),
                         "relmse_std": float(np.std(errs)), "bias2": bias2, "variance": variance,
                         "worse_than_mean": bool(np.mean(errs) > np.mean(mean_err))})
    # Crop where the paper's linear domain goes most wrong (ringing, smeared fireflies).
    crops = {"mean": np.array(buffers[0].mean)}
    crops.update({f"{d} c_s={c:g}": img for (d, c), img in outputs.items()})
    return rows, crops


def defaults_sweep(scene: Any, reference: FloatArray, config: BenchmarkConfig,
                   seed0: SampleBuffer | None) -> list[dict[str, Any]]:
    """relMSE of one default changed at a time (mean over seeds), at ``defaults_spp``.

    Reconstruction settings (levels, wavelet, mode) on uniform buffers; sampler settings
    (``uniform_fraction``, ``noise_model``, ``level_weight``, round size) with :class:`AdaptiveSampler` and the
    default reconstruction, with the sampler's CPU time as a share of the tracer's.

    Parameters
    ----------
    scene
        The scene.
    reference
        Its reference image.
    config
        ``defaults_spp``, ``defaults_seeds``, ``seed`` and ``threads`` are used.
    seed0
        The uniform buffer at ``defaults_spp`` already rendered with ``config.seed``, if any.

    Returns
    -------
    list of dict
        One row per setting: ``group``, ``value``, ``spp``, ``relmse`` (mean), ``relmse_each``,
        ``default`` and ``sampler_cpu_share`` (sampler settings only).
    """
    spp = config.defaults_spp
    seeds = [config.seed + s for s in range(config.defaults_seeds)]
    uniform = [seed0 if (s == config.seed and seed0 is not None) else render_uniform(scene, spp, s, config.threads)
               for s in seeds]
    rows: list[dict[str, Any]] = []

    def add(group: str, value: str, errors: list[float], default: bool, overhead: float | None = None) -> None:
        rows.append({"group": group, "value": value, "spp": spp, "relmse": float(np.mean(errors)),
                     "relmse_each": errors, "default": default, "sampler_cpu_share": overhead})

    add("plain mean", "uniform", [relmse(b.mean, reference) for b in uniform], False)
    _reconstruction_settings(add, (scene.height, scene.width), uniform, reference)
    _sampler_settings(add, scene, reference, config, seeds)
    return rows


def _reconstruction_settings(add: Callable[..., None], shape: tuple[int, int], uniform: list[SampleBuffer],
                             reference: FloatArray) -> None:
    """Levels, wavelet and mode of ``reconstruct`` on the uniform buffers."""
    lv_default = default_levels(shape)
    for lv in sorted(set(range(1, min(6, max_levels(shape)) + 1))):
        add("levels", str(lv), [relmse(reconstruct(b, levels=lv), reference) for b in uniform], lv == lv_default)
    for wav in ("bior4.4", "haar", "db2", "sym4"):
        add("wavelet", wav, [relmse(reconstruct(b, wavelet=wav), reference) for b in uniform], wav == "bior4.4")
    for mode in ("channels", "luminance"):
        add("mode", mode, [relmse(reconstruct(b, mode=mode), reference) for b in uniform], mode == "channels")


def _sampler_settings(add: Callable[..., None], scene: Any, reference: FloatArray, config: BenchmarkConfig,
                      seeds: list[int]) -> None:
    """``AdaptiveSampler`` options; the defaults of every group share one set of renders."""
    shape = (scene.height, scene.width)
    spp = config.defaults_spp
    variants = [("uniform_fraction", v, {"uniform_fraction": v}, v == 0.0) for v in (0.0, 0.1, 0.3)]
    # The level weight acts only in the paper's level model, no longer the default noise model.
    variants += [("noise_model", m, {"noise_model": m} | ({"level_weight": 0.25} if m == "levels" else {}),
                  m == DEFAULT_NOISE_MODEL) for m in ("shrinkage", "levels")]
    variants += [("level_weight (noise_model levels)", v, {"noise_model": "levels", "level_weight": v}, False)
                 for v in (0.0, 0.25, 1.0)]
    variants += [("round_spp", v, {"round_spp": v}, False) for v in (0.25, 2.0, 8.0)]
    variants += [("round_growth", v, {"round_growth": v}, v == DEFAULT_ROUND_GROWTH) for v in (0.25, 0.5, 1.0)]
    variants += [("initial_spp", v, {"initial_spp": v}, v == DEFAULT_AWR_INITIAL_SPP) for v in (1, 2, 4, 8)]
    cache: dict[tuple, tuple[list[float], float]] = {}
    for group, value, options, default in variants:
        key = tuple(sorted((k, v) for k, v in options.items() if not default))
        if key not in cache:
            errs, render_cpu, sampler_cpu = [], 0.0, 0.0
            for s in seeds:
                pt = make_tracer(scene, s, config.threads)
                got: dict[str, Any] = {}
                try:
                    run_progressive(AdaptiveSampler(shape, seed=s, **options), pt, [spp],
                                    lambda _spp, buf, timing: got.update(buffer=buf, timing=timing))
                finally:
                    pt.close()
                errs.append(relmse(reconstruct(got["buffer"]), reference))
                render_cpu += got["timing"].render_cpu
                sampler_cpu += got["timing"].sampler_cpu
            cache[key] = (errs, sampler_cpu / render_cpu if render_cpu > 0 else float("nan"))
        errs, share = cache[key]
        add(group, str(value), errs, default, share)
