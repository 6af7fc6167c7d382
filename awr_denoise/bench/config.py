"""What the benchmark measures: its configuration, the methods compared and the image sizes."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from ..domains import Domain

__all__ = ["BenchmarkConfig", "METHODS", "METHOD_LABELS", "DOMAINS", "OVERHEAD_SIZES"]

METHODS = ("uniform", "uniform+awr", "awr+awr", "awr-levels+awr", "awr-gain+awr", "variance+awr", "uniform+skimage",
           "uniform+oidn")
"""Methods compared at equal samples. ``sampler+reconstruction``; ``uniform`` is the plain mean; ``awr`` is
``AdaptiveSampler()``, ``awr-levels`` the same with the paper's level term (``noise_model="levels"``), ``awr-gain``
with the measured gain (``noise_model="reconstruction"``)."""

METHOD_LABELS = {
    "uniform": "uniform MC (mean)",
    "uniform+awr": "uniform + AWR reconstruction",
    "awr+awr": "AWR sampling + AWR reconstruction",
    "awr-levels+awr": "AWR sampling by the paper's levels + AWR reconstruction",
    "awr-gain+awr": "AWR sampling by the measured noise gain + AWR reconstruction",
    "variance+awr": "variance sampling + AWR reconstruction",
    "uniform+skimage": "uniform + skimage BayesShrink",
    "uniform+oidn": "uniform + OIDN",
}
"""Legend text of every method in the figures."""

DOMAINS: dict[str, Domain] = {
    "linear": Domain("linear"),
    "log": Domain("log"),
    "gamma": Domain("gamma"),
    "log robust": Domain("log", robust=True),
}
"""Thresholding domains of the ``c_s`` sweep (the paper's linear domain and the stabilised ones)."""

OVERHEAD_SIZES = {"256x256": (256, 256), "1080p": (1080, 1920), "4K": (2160, 3840)}
"""Image sizes ``(height, width)`` of the overhead measurement, by name."""


@dataclass(frozen=True)
class BenchmarkConfig:
    """What :func:`awr_denoise.bench.run_benchmark` measures.

    Parameters
    ----------
    scenes
        Bundled scene names; ``None`` for all of them.
    spps
        Average samples per pixel at which every method is measured.
    uniform_max_spp
        The uniform Monte Carlo curve (for equal-error sample counts) is rendered at powers of
        two from 4 up to this.
    width, height
        Resolution override; ``None`` keeps each scene's default (128x128). At another
        resolution the reference is rendered on the fly (``inline_reference_spp``, not cached).
    reference_spp
        Minimum spp of the cached references; a cached reference below it is re-rendered (and
        cached) with :func:`awr_denoise.tracer.load_reference`. ``None`` uses the cached files
        as they are (rendering the tracer's default when one is missing).
    inline_reference_spp
        spp of references rendered on the fly at a non-default resolution.
    sweep_spp, sweep_seeds, c_s_values
        The ``c_s`` / domain sweep: uniform buffers at ``sweep_spp`` for ``sweep_seeds`` seeds.
    defaults_sweep, defaults_spp, defaults_seeds
        Sweep of the other defaults at ``defaults_spp`` over ``defaults_seeds`` seeds.
    overhead_sizes
        Image sizes of the overhead measurement (names of :data:`OVERHEAD_SIZES`).
    overhead_levels, overhead_levels_size
        Levels of the overhead-against-levels measurement, and the image size it uses.
    oidn
        Try Intel Open Image Denoise (skipped when its Python bindings are missing).
    threads
        Tracer threads.
    mitsuba
        Also measure the Mitsuba 3 scenes through the adapter (skipped, with the reason on the
        page, when the ``mitsuba`` extra cannot start).
    mitsuba_scenes, mitsuba_size, mitsuba_reference_spp, mitsuba_reference_dir
        Which Mitsuba scenes (``None``: :data:`~awr_denoise.adapters.mitsuba_scenes.SCENE_NAMES`), their
        side in pixels, the spp of their references, and where the references are cached
        (``None``: ``data/cache/mitsuba/`` of the source tree).
    seed
        Seed of the main renders (every method uses the same one: common random numbers).
    flag_seeds
        Seeds in all over which a flag (a default worse than the plain mean on the main render) is
        checked: the main seed and the ones after it (:mod:`awr_denoise.bench.flagcheck`); 1
        leaves flags unchecked.

    Examples
    --------
    >>> BenchmarkConfig().spps
    (4, 8, 16, 32, 64, 128)
    >>> BenchmarkConfig(scenes=("cornell_gi",)).uniform_max_spp
    1024
    """

    scenes: tuple[str, ...] | None = None
    spps: tuple[int, ...] = (4, 8, 16, 32, 64, 128)
    uniform_max_spp: int = 1024
    width: int | None = None
    height: int | None = None
    reference_spp: int | None = None
    inline_reference_spp: int = 1024
    sweep_spp: int = 16
    sweep_seeds: int = 4
    c_s_values: tuple[float, ...] = (0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0)
    defaults_sweep: bool = True
    defaults_spp: int = 32
    defaults_seeds: int = 2
    overhead_sizes: tuple[str, ...] = ("256x256", "1080p", "4K")
    overhead_levels: tuple[int, ...] = (1, 2, 3, 4, 5)
    overhead_levels_size: str = "1080p"
    oidn: bool = True
    threads: int = 2
    mitsuba: bool = True
    mitsuba_scenes: tuple[str, ...] | None = None
    mitsuba_size: int = 128
    mitsuba_reference_spp: int = 2048
    mitsuba_reference_dir: str | None = None
    seed: int = 0
    flag_seeds: int = 6

    @classmethod
    def quick(cls, **overrides: Any) -> BenchmarkConfig:
        """The quick mode: fewer sample counts, seeds and sizes (a few minutes).

        Parameters
        ----------
        **overrides
            Fields to change on top of the quick mode's values.

        Returns
        -------
        BenchmarkConfig
            The quick configuration.

        Examples
        --------
        >>> config = BenchmarkConfig.quick(scenes=("default",))
        >>> config.spps, config.uniform_max_spp, config.defaults_sweep, config.scenes
        ((4, 8, 32), 256, False, ('default',))
        """
        base = cls(spps=(4, 8, 32), uniform_max_spp=256, mitsuba_size=64, mitsuba_reference_spp=512, sweep_spp=8, sweep_seeds=3,
                   c_s_values=(0.25, 0.5, 1.0, 2.0, 4.0), defaults_sweep=False, overhead_sizes=("256x256", "1080p"),
                   overhead_levels=(1, 3, 5), overhead_levels_size="256x256", flag_seeds=3)
        return replace(base, **overrides)
