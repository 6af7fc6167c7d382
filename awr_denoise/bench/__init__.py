"""The speed/accuracy benchmark on the bundled path-traced scenes (``awr bench``).

One call renders every bundled scene with the tracer (:mod:`awr_denoise.tracer`) and measures,
against each scene's high-spp reference (how quality is measured: docs/benchmarks.md):

- error (relMSE with ``eps = 0.01``, MSE, PSNR, SSIM on the tonemapped image) against the
  average sample count for uniform Monte Carlo, uniform sampling + AWR reconstruction, AWR
  adaptive sampling + AWR reconstruction (the paper, sections 4-5), per-pixel variance-driven
  sampling + AWR reconstruction, and peer denoisers on the same uniform buffers
  (scikit-image's ``denoise_wavelet`` with BayesShrink, and Intel Open Image Denoise when its
  Python bindings are installed);
- the equal-error sample count of every result: the uniform Monte Carlo spp that reaches the
  same relMSE, interpolated in log-log on a uniform curve rendered up to 1024 spp, after
  removing the reference's own noise floor (the paper's headline is "AWR at 32 spp is near
  Monte Carlo at 512 spp");
- error against wall time, with sampling (``ask``/``tell``) and reconstruction included;
- error, squared bias and variance (over several seeds) against the smoothing constant
  ``c_s`` for the linear domain and each stabilised domain, with crops of the artefacts;
- a sweep of the other defaults (levels, wavelet, mode, ``uniform_fraction``,
  ``level_weight``, round size) on the path-traced scenes;
- the overhead of the priority computation per round and of the reconstruction at 256x256,
  1080p and 4K, and how it grows with the number of levels.

It writes ``benchmarks/results/quality.json`` (raw numbers), PNG figures under
``docs/img/`` and ``docs/benchmarks.md``. Run it with::

    python -m awr_denoise.bench            # full run (see docs/benchmarks.md for its time)
    python -m awr_denoise.bench --quick    # a few minutes

Needs the ``tracer`` and ``bench`` extras (``pip install "awr-denoise[tracer,bench]"``).

Modules: :mod:`~awr_denoise.bench.config` (what is measured), :mod:`~awr_denoise.bench.runner`
(the run, one scene at a time), :mod:`~awr_denoise.bench.sweeps` and
:mod:`~awr_denoise.bench.overhead` (its parts), :mod:`~awr_denoise.bench.rendering` (the
tracer), :mod:`~awr_denoise.bench.peers` (the other denoisers),
:mod:`~awr_denoise.bench.analysis` (noise floor, equal-error spp, summary),
:mod:`~awr_denoise.bench.figures` and :mod:`~awr_denoise.bench.report` (the page),
:mod:`~awr_denoise.bench.command` (the command line), and the functions the scripts in
``benchmarks/`` share: :mod:`~awr_denoise.bench.measure` (timing, memory, synthetic buffers),
:mod:`~awr_denoise.bench.records` (results files) and :mod:`~awr_denoise.bench.cache` (cached buffers and
references, written whole and read back only whole).
"""

from __future__ import annotations

from .analysis import equal_error_spp, fit_noise_floor
from .command import add_arguments, main, run_from_args
from .config import DOMAINS, METHODS, OVERHEAD_SIZES, BenchmarkConfig
from .measure import median_time, noisy_buffer, peak_memory, timed
from .peers import oidn_available, oidn_denoise, skimage_denoise
from .records import command_line, json_ready, load_average, machine_info, update_section, write_json
from .runner import run_benchmark

__all__ = [
    "BenchmarkConfig",
    "DOMAINS",
    "METHODS",
    "OVERHEAD_SIZES",
    "add_arguments",
    "command_line",
    "equal_error_spp",
    "fit_noise_floor",
    "json_ready",
    "load_average",
    "machine_info",
    "main",
    "median_time",
    "noisy_buffer",
    "oidn_available",
    "oidn_denoise",
    "peak_memory",
    "run_benchmark",
    "run_from_args",
    "skimage_denoise",
    "timed",
    "update_section",
    "write_json",
]
