"""The Mitsuba 3 scenes in ``awr bench``: every default judged on a renderer the project did not write.

The bundled tracer's scenes chose the library's defaults; a renderer written by others is the
check that they transfer. For every scene of :mod:`awr_denoise.adapters.mitsuba_scenes`,
rendered through the Mitsuba adapter (extra ``mitsuba``), at every measured spp: uniform
sampling (its plain mean and the default reconstruction) and AWR sampling (its plain mean and
the default reconstruction), each with relMSE, MSE and the image mean's error against a
high-spp render of the same adapter. A missing extra, or a Mitsuba that cannot start, skips
the section with the reason, which the page shows.

References are rendered once per scene, size, spp and Mitsuba version and cached as ``.npy``
files in ``data/cache/mitsuba/`` in a checkout, ``mitsuba`` in the user's cache folder in an install
(``BenchmarkConfig.mitsuba_reference_dir``), with a seed no measured render uses.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .._places import cache_folder, checkout_data
from .._typing import FloatArray
from ..buffers import SampleBuffer
from ..metrics import mse, relmse
from ..reconstruct import reconstruct
from ..requests import SampleRequest
from ..sampling import AdaptiveSampler, UniformSampler
from .cache import load_arrays, save_arrays
from .config import BenchmarkConfig
from .measure import Timing, run_progressive

__all__ = ["MITSUBA_METHODS", "mitsuba_benchmark", "mitsuba_scene_names", "mitsuba_status", "default_reference_dir"]

MITSUBA_METHODS = ("uniform", "uniform+awr", "awr", "awr+awr")
"""``uniform``/``awr``: the plain mean of uniform / AWR sampling; ``+awr``: the default reconstruction of it."""

def default_reference_dir() -> Path:
    """Where references are cached: a checkout's ``data/cache/mitsuba`` (not tracked), an install's
    ``$XDG_CACHE_HOME/awr-denoise/mitsuba`` (by default under ``~/.cache``); an install wrote them into
    ``site-packages/data``, which made later runs take it for a checkout (an attack pass). Asked when used, not at
    import: a process without a home folder imported the benchmark only to fail.

    Examples
    --------
    >>> from awr_denoise.bench.mitsuba import default_reference_dir
    >>> default_reference_dir().name
    'mitsuba'
    """
    data = checkout_data()
    return (cache_folder() if data is None else data / "cache") / "mitsuba"

_REFERENCE_SEED = 1 << 30  # no measured render uses it
_REFERENCE_BATCH_SPP = 64  # a reference is rendered in requests of this many spp (bounded memory)

Tick = Callable[[str], None]


def mitsuba_status() -> str | None:
    """``None`` when the Mitsuba adapter can render here, else why not (one line, with the hint).

    Examples
    --------
    >>> from awr_denoise.bench.mitsuba import mitsuba_status
    >>> status = mitsuba_status()
    >>> status is None or isinstance(status, str)
    True
    """
    try:
        from ..adapters._mitsuba_runtime import import_mitsuba  # extra "mitsuba", imported lazily

        import_mitsuba()
    except (ImportError, RuntimeError) as exc:
        return f"skipped: the Mitsuba 3 adapter cannot start ({exc}; pip install \"awr-denoise[mitsuba]\")"
    return None


def mitsuba_scene_names(config: BenchmarkConfig) -> list[str]:
    """The Mitsuba scenes ``config`` asks for (the four benchmark scenes, ``SCENE_NAMES``, by default; the scenes lit
    through rare paths on request); unknown names refused.

    Examples
    --------
    >>> from awr_denoise.bench import BenchmarkConfig
    >>> from awr_denoise.bench.mitsuba import mitsuba_scene_names
    >>> mitsuba_scene_names(BenchmarkConfig())
    ['cornell_box', 'envmap_sun', 'glossy_glass', 'dof_checker']
    """
    # Only scene descriptions: importing this module needs numpy, not Mitsuba.
    from ..adapters.mitsuba_scenes import ALL_SCENES, SCENE_NAMES

    names = list(config.mitsuba_scenes) if config.mitsuba_scenes else list(SCENE_NAMES)
    for name in names:
        if name not in ALL_SCENES:
            raise ValueError(f"mitsuba_scenes: {name!r} is not one of {', '.join(ALL_SCENES)}")
    return names


def _reference(name: str, shape: tuple[int, int], spp: int, reference_dir: Path) -> tuple[FloatArray, str]:
    """The scene's reference (cached), and where it came from."""
    import mitsuba as mi  # extra "mitsuba"; mitsuba_status() checked it

    from ..adapters.mitsuba import create_renderer

    path = reference_dir / f"{name}_{shape[0]}x{shape[1]}_{spp}spp_mitsuba{mi.__version__}.npy"
    cached = load_arrays(path, lambda a: None if a.shape == (*shape, 3) and np.isfinite(a).all()
                         else f"shape {a.shape} or values not finite, not a {shape[0]}x{shape[1]} reference")
    if cached is not None:
        return cached, f"cached {path.name}"
    renderer = create_renderer(name, shape=shape, seed=_REFERENCE_SEED)
    total: SampleBuffer | None = None
    for first in range(0, spp, _REFERENCE_BATCH_SPP):
        part = renderer(SampleRequest.uniform(shape, min(_REFERENCE_BATCH_SPP, spp - first), first_index=first))
        total = part if total is None else total.merge(part)
    assert total is not None
    image = np.asarray(total.mean)
    save_arrays(path, image)
    return image, f"rendered {path.name}"


def _row(spp: int, image: FloatArray, reference: FloatArray) -> dict[str, float]:
    ref_mean = float(reference.mean())
    return {"spp": spp, "relmse": relmse(image, reference), "mse": mse(image, reference),
            "mean_error": float(image.mean()) / ref_mean - 1.0 if ref_mean > 0 else float("nan")}


def mitsuba_benchmark(config: BenchmarkConfig, tick: Tick) -> dict[str, Any]:
    """Measure the Mitsuba scenes; ``{"status": ..., "scenes": {name: {...}}}``.

    Parameters
    ----------
    config
        ``mitsuba_scenes``, ``mitsuba_size``, ``mitsuba_reference_spp``,
        ``mitsuba_reference_dir``, ``spps`` and ``seed`` are used.
    tick
        Called with a label after each scene.

    Returns
    -------
    dict
        ``status`` (``"measured"`` or why the section was skipped) and, per scene, ``shape``,
        ``reference`` (its spp and source) and ``methods`` (:data:`MITSUBA_METHODS` -> rows of
        ``spp``, ``relmse``, ``mse``, ``mean_error``).
    """
    status = mitsuba_status()
    if status is not None:
        return {"status": status, "scenes": {}}
    from ..adapters.mitsuba import create_renderer  # extra "mitsuba", available (checked above)

    names = mitsuba_scene_names(config)
    shape = (int(config.mitsuba_size), int(config.mitsuba_size))
    reference_dir = Path(config.mitsuba_reference_dir) if config.mitsuba_reference_dir else default_reference_dir()
    spps = sorted(set(int(s) for s in config.spps))
    out: dict[str, Any] = {"status": "measured", "scenes": {}}
    for name in names:
        reference, source = _reference(name, shape, config.mitsuba_reference_spp, reference_dir)
        methods: dict[str, list[dict[str, float]]] = {m: [] for m in MITSUBA_METHODS}
        for sampler_cls, plain, denoised in ((UniformSampler, "uniform", "uniform+awr"),
                                             (AdaptiveSampler, "awr", "awr+awr")):
            renderer = create_renderer(name, shape=shape, seed=config.seed)

            def snapshot(spp: int, buffer: SampleBuffer, timing: Timing,
                         plain: str = plain, denoised: str = denoised) -> None:
                methods[plain].append(_row(spp, np.asarray(buffer.mean), reference))
                methods[denoised].append(_row(spp, reconstruct(buffer), reference))

            run_progressive(sampler_cls(shape, seed=config.seed), renderer, spps, snapshot)
        out["scenes"][name] = {"shape": list(shape), "methods": methods,
                               "reference": {"spp": config.mitsuba_reference_spp, "source": source}}
        tick(f"mitsuba {name}")
    return out
