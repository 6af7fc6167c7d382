"""The library's own cost: one adaptive ``ask()`` round and one ``reconstruct`` per image size and depth."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ..priorities import sampling_density
from ..reconstruct import reconstruct
from ..sampling import AdaptiveSampler
from .config import OVERHEAD_SIZES, BenchmarkConfig
from .measure import median_time, noisy_buffer

__all__ = ["measure_overhead"]


def measure_overhead(config: BenchmarkConfig, tick: Callable[[str], None]) -> dict[str, Any]:
    """Time of one ``ask()`` round (priorities + allocation) and of ``reconstruct`` per size and level.

    One core, median of repeated calls after a warm-up call that builds the cached wavelet
    operators (as a render loop would), on a synthetic 4-spp buffer (:func:`noisy_buffer`).

    Parameters
    ----------
    config
        ``overhead_sizes``, ``overhead_levels`` and ``overhead_levels_size`` are used.
    tick
        Called with a label after each stage (progress).

    Returns
    -------
    dict
        ``sizes``: per size, seconds of ``reconstruct``, ``sampling_density`` and ``ask()``, and
        per megapixel; ``levels``: ``reconstruct`` and ``ask()`` seconds per number of levels.

    Examples
    --------
    >>> from awr_denoise.bench import BenchmarkConfig
    >>> config = BenchmarkConfig(overhead_sizes=(), overhead_levels=(1,), overhead_levels_size="256x256")
    >>> measure_overhead(config, tick=lambda label: None)["levels"][0]["levels"]
    1
    """
    sizes = []
    for name in config.overhead_sizes:
        shape = OVERHEAD_SIZES[name]
        buf = noisy_buffer(shape)
        repeats = 5 if shape[0] * shape[1] < 1e6 else 2
        reconstruct(buf)  # warm the cached wavelet operators, as a render loop would
        t_rec = median_time(lambda: reconstruct(buf), repeats)
        t_den = median_time(lambda: sampling_density(buf), repeats)
        t_ask = median_time(lambda: AdaptiveSampler.from_buffer(buf, round=1).ask(), repeats)
        mp = shape[0] * shape[1] / 1e6
        sizes.append({"size": name, "pixels": shape[0] * shape[1], "reconstruct_s": t_rec, "priorities_s": t_den,
                      "ask_s": t_ask, "reconstruct_s_per_mp": t_rec / mp, "ask_s_per_mp": t_ask / mp})
        tick(f"overhead {name}")
    levels = []
    lv_size = config.overhead_levels_size
    buf = noisy_buffer(OVERHEAD_SIZES[lv_size])
    for lv in config.overhead_levels:
        reconstruct(buf, levels=lv)
        t_rec = median_time(lambda: reconstruct(buf, levels=lv), 2)
        t_ask = median_time(lambda: AdaptiveSampler.from_buffer(buf, round=1, levels=lv).ask(), 2)
        levels.append({"size": lv_size, "levels": lv, "reconstruct_s": t_rec, "ask_s": t_ask})
    tick("overhead levels")
    return {"sizes": sizes, "levels": levels}
