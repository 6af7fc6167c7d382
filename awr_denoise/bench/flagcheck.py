"""Flags checked over seeds: a default worse than the plain mean, or one unlucky render?

A flag (:func:`~awr_denoise.bench.analysis.summarize`) compares one render (the benchmark's
seed) of a method with library defaults against the plain mean at equal samples. Where a few
pixels hold the squared error (a small, very bright source), that one render's MSE moves by tens
of percent from seed to seed, and a reconstruction that lowers the expected error can be above
the plain mean on one seed and below it on the next. Every flagged (scene, method, spp) is
therefore rendered again with further seeds, method and plain mean on the same samples, and
:func:`~awr_denoise.bench.analysis.summarize` confirms the flag when the error summed over all
seeds is above the plain mean's summed error; otherwise it reports the flag as not confirmed,
with the per-seed ratios either way (docs/benchmarks.md, "Flags").
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

from ..reconstruct import reconstruct
from ..sampling import AdaptiveSampler, Sampler, UniformSampler, VarianceSampler
from .analysis import flag_candidates, image_metrics
from .config import BenchmarkConfig
from .measure import run_progressive
from .rendering import make_tracer, reference_image, tracer_module

__all__ = ["ADAPTIVE_METHODS", "check_flags", "method_and_plain"]

ADAPTIVE_METHODS: dict[str, Callable[..., Sampler]] = {
    "awr+awr": AdaptiveSampler,
    "awr-levels+awr": functools.partial(AdaptiveSampler, noise_model="levels"),
    "awr-gain+awr": functools.partial(AdaptiveSampler, noise_model="reconstruction"),
    "variance+awr": VarianceSampler,
}
"""The benchmark's adaptive methods: the sampler each renders with (the reconstruction is the default)."""


def _render(sampler: Sampler, scene: Any, targets: list[int], seed: int, threads: int) -> Any:
    """The buffer of ``sampler`` driven through ``targets`` (spp) by the tracer with render seed ``seed``."""
    kept: list = []
    renderer = make_tracer(scene, seed, threads)
    try:
        run_progressive(sampler, renderer, targets, lambda _spp, buffer, _timing: kept.append(buffer))
    finally:
        renderer.close()
    return kept[-1]


def method_and_plain(method: str, scene: Any, targets: list[int], seed: int, threads: int) -> tuple[Any, Any]:
    """``(method's image, plain mean)`` at the last of ``targets`` (spp) for one seed, as the main run makes them.

    The samplers stop at every target on the way, as in the main run (its rounds are cut there).
    ``uniform+awr`` reconstructs the uniform buffer whose mean is the plain mean; an adaptive
    method reconstructs its own buffer, and the plain mean is the uniform render of the same seed
    and spp (equal samples).
    """
    shape = (scene.height, scene.width)
    uniform = _render(UniformSampler(shape, seed=seed), scene, targets, seed, threads)
    if method == "uniform+awr":
        return reconstruct(uniform), uniform.mean
    adaptive = _render(ADAPTIVE_METHODS[method](shape, seed=seed), scene, targets, seed, threads)
    return reconstruct(adaptive), uniform.mean


def check_flags(results: dict[str, Any], config: BenchmarkConfig,
                tick: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """Every flagged (scene, method, spp) of ``results`` measured again on further seeds.

    Parameters
    ----------
    results
        The benchmark's raw results (``scenes``, as :func:`~awr_denoise.bench.run_benchmark`
        builds them).
    config
        The configuration they were measured with; ``flag_seeds`` seeds in all are used, the
        main run's (``seed``) and the ones after it.
    tick
        Called with a label after each check (progress).

    Returns
    -------
    list of dict
        One entry per flagged (scene, method, spp): ``seeds`` and, per seed in that order, the
        method's ``relmse`` and ``mse`` and the plain mean's ``plain_relmse`` and ``plain_mse``
        (the main run's seed taken from ``results``).
    """
    checks = []
    for name, method, spp in flag_candidates(results):
        rows = results["scenes"][name]["methods"]
        first = next(r for r in rows[method] if r["spp"] == spp)
        plain = next(r for r in rows["uniform"] if r["spp"] == spp)
        entry: dict[str, Any] = {"scene": name, "method": method, "spp": spp, "seeds": [config.seed],
                                 "relmse": [first["relmse"]], "mse": [first["mse"]],
                                 "plain_relmse": [plain["relmse"]], "plain_mse": [plain["mse"]]}
        scene = tracer_module().load_scene(name, width=config.width, height=config.height)
        reference, _ = reference_image(name, scene, config)
        targets = sorted(s for s in set(int(s) for s in config.spps) if s <= spp)
        for seed in range(config.seed + 1, config.seed + config.flag_seeds):
            image, mean = method_and_plain(method, scene, targets, seed, config.threads)
            got, base = image_metrics(image, reference), image_metrics(mean, reference)
            entry["seeds"].append(seed)
            for key in ("relmse", "mse"):
                entry[key].append(got[key])
                entry[f"plain_{key}"].append(base[key])
        checks.append(entry)
        if tick is not None:
            tick(f"{name}: {method} at {spp} spp over {config.flag_seeds} seeds")
    return checks
