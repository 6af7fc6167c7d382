"""The benchmark's PNG figures (``docs/img/bench_*.png``), drawn with matplotlib.

matplotlib is an optional extra (``bench``), imported when the figures are drawn, with an
install hint. Figures are built on :class:`matplotlib.figure.Figure` directly (no pyplot
state), so drawing them leaves an interactive matplotlib untouched.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

from .._typing import FloatArray
from ..metrics import RELMSE_EPSILON, relmse, tonemap
from .config import DOMAINS, METHOD_LABELS, METHODS

__all__ = ["PLOT_HINT", "FIGURE_FILES", "require_matplotlib", "write_figures", "error_window"]

PLOT_HINT = 'the benchmark plots need matplotlib; install it with pip install "awr-denoise[bench]"'

_COLORS = {"uniform": "black", "uniform+awr": "tab:blue", "awr+awr": "tab:red", "awr-levels+awr": "tab:pink",
           "awr-gain+awr": "tab:brown",
           "variance+awr": "tab:orange",
           "uniform+skimage": "tab:green", "uniform+oidn": "tab:purple"}
_DOMAIN_COLORS = {"linear": "tab:gray", "log": "tab:blue", "gamma": "tab:green", "log robust": "tab:red"}


FIGURE_FILES = {"error_vs_spp": "bench_error_vs_spp.png", "error_vs_time": "bench_error_vs_time.png",
                "density": "bench_density.png", "crops": "bench_crops.png", "cs_relmse": "bench_cs_relmse.png",
                "cs_bias_variance": "bench_cs_bias_variance.png", "domain_crops": "bench_domain_crops.png",
                "overhead": "bench_overhead.png"}
"""The file of each figure :func:`write_figures` may draw, in ``img/`` (checked before a run: all of them)."""


def require_matplotlib() -> type:
    """matplotlib's ``Figure`` class (Agg backend), or an :class:`ImportError` with the install hint.

    Raises
    ------
    ImportError
        matplotlib (extra ``bench``) is not installed.
    """
    try:
        import matplotlib  # optional extra "bench", imported lazily

        matplotlib.use("Agg", force=False)
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise ImportError(PLOT_HINT) from exc
    return Figure


def write_figures(results: dict[str, Any], images: dict[str, Any], img_dir: Path, *,
                  place: Callable[[Path], Path] | None = None) -> dict[str, str]:
    """Draw every figure of ``docs/benchmarks.md`` into ``img_dir``.

    Parameters
    ----------
    results
        The raw results of :func:`awr_denoise.bench.run_benchmark`.
    images
        Per scene, the images kept by :func:`awr_denoise.bench.runner.scene_benchmark`.
    img_dir
        Where the PNG files go (created).
    place
        Where each figure's file is written instead of its name in ``img_dir`` (a temporary,
        moved into place with the run's other outputs), e.g. :meth:`OutputSet.add
        <awr_denoise.io.atomic.OutputSet.add>`.

    Returns
    -------
    dict
        File name of each figure drawn, by key (``error_vs_spp``, ``error_vs_time``,
        ``density``, ``crops``, ``cs_relmse``, ``cs_bias_variance``, ``domain_crops`` and, when
        the overhead was measured, ``overhead``).
    """
    figure = require_matplotlib()
    img_dir.mkdir(parents=True, exist_ok=True)
    scenes = list(results["scenes"])
    figs: dict[str, str] = {}
    files = {key: img_dir / name for key, name in FIGURE_FILES.items()}
    figs["error_vs_spp"] = _save(_error_vs_spp(figure, results, scenes), files["error_vs_spp"], place=place)
    figs["error_vs_time"] = _save(_error_vs_time(figure, results, scenes), files["error_vs_time"], place=place)
    figs["density"] = _save(_density(figure, images, scenes), files["density"], place=place)
    figs["crops"] = _save(_crops(figure, images, scenes), files["crops"], dpi=90, place=place)
    for key, fields in (("cs_relmse", ("relmse",)), ("cs_bias_variance", ("bias2", "variance"))):
        figs[key] = _save(_cs_sweep(figure, results, scenes, key, fields), files[key], place=place)
    figs["domain_crops"] = _save(_domain_crops(figure, images, scenes), files["domain_crops"], dpi=90, place=place)
    ov = results.get("overhead", {})
    if ov.get("sizes"):
        figs["overhead"] = _save(_overhead(figure, ov), files["overhead"], place=place)
    return figs


def error_window(error_map: FloatArray, size: int) -> tuple[slice, slice]:
    """The ``size`` x ``size`` window with the largest summed error (where a crop shows most).

    Examples
    --------
    >>> y, x = np.mgrid[0:32, 0:32]
    >>> err = np.exp(-((y - 20) ** 2 + (x - 10) ** 2) / 8.0)
    >>> error_window(err, 9)
    (slice(16, 25, None), slice(6, 15, None))
    """
    h, w = error_map.shape
    size = min(size, h, w)
    local = ndimage.uniform_filter(error_map, size, mode="constant")
    half = size // 2
    inner = local[half:h - (size - half) + 1, half:w - (size - half) + 1]
    r, c = (int(i) for i in np.unravel_index(int(np.argmax(inner)), inner.shape))
    return slice(r, r + size), slice(c, c + size)


def _save(fig: Any, path: Path, dpi: int = 80, place: Callable[[Path], Path] | None = None) -> str:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path if place is None else place(path), dpi=dpi, bbox_inches="tight", format="png")
    return path.name


def _grid(n: int) -> tuple[int, int]:
    cols = min(3, n)
    return (n + cols - 1) // cols, cols


def _error_vs_spp(figure: type, results: dict[str, Any], scenes: list[str]) -> Any:
    """relMSE against spp (log-log) per scene; the floor-corrected uniform curve dotted."""
    rows_n, cols_n = _grid(len(scenes))
    fig = figure(figsize=(4.2 * cols_n, 3.3 * rows_n))
    for i, name in enumerate(scenes):
        ax = fig.add_subplot(rows_n, cols_n, i + 1)
        sc = results["scenes"][name]
        curve = sc["uniform_curve"]
        ax.loglog([r["spp"] for r in curve], [r["relmse"] for r in curve], color="black", lw=1, label="uniform MC")
        corr = [(r["spp"], r["relmse_corrected"]) for r in curve if r["relmse_corrected"] > 0]
        if corr:
            ax.loglog(*zip(*corr), color="black", lw=1, ls=":", label="uniform MC, floor removed")
        for meth, rows in sc["methods"].items():
            if meth == "uniform":
                continue
            ax.loglog([r["spp"] for r in rows], [r["relmse"] for r in rows], "o-", ms=3, color=_COLORS[meth],
                      label=METHOD_LABELS[meth])
        floor = sc["reference"]["floor_fit"]
        if floor > 0:
            ax.axhline(floor, color="gray", lw=0.8, ls="--", label="reference noise floor")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("average spp")
        ax.set_ylabel(f"relMSE (eps {RELMSE_EPSILON:g})")
        ax.grid(True, which="both", alpha=0.3)
        if i == 0:
            ax.legend(fontsize=6.5)
    fig.tight_layout()
    return fig


def _error_vs_time(figure: type, results: dict[str, Any], scenes: list[str]) -> Any:
    """relMSE against the loop's CPU time per scene."""
    rows_n, cols_n = _grid(len(scenes))
    fig = figure(figsize=(4.2 * cols_n, 3.3 * rows_n))
    for i, name in enumerate(scenes):
        ax = fig.add_subplot(rows_n, cols_n, i + 1)
        sc = results["scenes"][name]
        curve = sc["uniform_curve"]
        ax.loglog([r["total_cpu_s"] for r in curve], [r["relmse"] for r in curve], color="black",
                  lw=1, label="uniform MC")
        for meth, rows in sc["methods"].items():
            if meth == "uniform":
                continue
            ax.loglog([r["total_cpu_s"] for r in rows], [r["relmse"] for r in rows], "o-", ms=3,
                      color=_COLORS[meth], label=METHOD_LABELS[meth])
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("CPU time: render + sampling + reconstruction (s)")
        ax.set_ylabel("relMSE")
        ax.grid(True, which="both", alpha=0.3)
        if i == 0:
            ax.legend(fontsize=6.5)
    fig.tight_layout()
    return fig


def _density(figure: type, images: dict[str, Any], scenes: list[str]) -> Any:
    """Sample density of the adaptive samplers, beside each scene's reference."""
    dens_methods = [m for m in ("awr+awr", "awr-levels+awr", "awr-gain+awr", "variance+awr") if all(m in images[s]["density"] for s in scenes)]
    cols = 1 + len(dens_methods)
    fig = figure(figsize=(2.2 * cols, 2.2 * len(scenes)))
    for i, name in enumerate(scenes):
        ax = fig.add_subplot(len(scenes), cols, i * cols + 1)
        ax.imshow(tonemap(images[name]["reference"]), interpolation="nearest")
        ax.set_axis_off()
        ax.set_title(f"{name}", fontsize=8)
        for j, meth in enumerate(dens_methods):
            ax = fig.add_subplot(len(scenes), cols, i * cols + 2 + j)
            d = images[name]["density"][meth]
            im = ax.imshow(np.log2(np.maximum(d, 1e-3)), cmap="magma", vmin=-2, vmax=3, interpolation="nearest")
            ax.set_axis_off()
            ax.set_title(f"{meth}, max {d.max():.1f}x", fontsize=7)
        if i == 0 and dens_methods:
            cb = fig.colorbar(im, ax=ax, fraction=0.046)
            cb.set_label("log2(spp / mean spp)", fontsize=6)
            cb.ax.tick_params(labelsize=6)
    fig.tight_layout()
    return fig


def _crops(figure: type, images: dict[str, Any], scenes: list[str]) -> Any:
    """Side-by-side crops of every method at the headline spp, where uniform MC errs most."""
    crop_methods = ["reference"] + [m for m in METHODS if all(m in images[s]["crops"] for s in scenes)]
    fig = figure(figsize=(1.9 * len(crop_methods), 2.05 * len(scenes)))
    for i, name in enumerate(scenes):
        ref = images[name]["reference"]
        size = max(16, min(ref.shape[:2]) // 3)
        err = np.mean((images[name]["crops"]["uniform"] - ref) ** 2 / (ref**2 + RELMSE_EPSILON), axis=-1)
        win = error_window(ndimage.gaussian_filter(err, 2), size)
        for j, meth in enumerate(crop_methods):
            img = ref if meth == "reference" else images[name]["crops"][meth]
            ax = fig.add_subplot(len(scenes), len(crop_methods), i * len(crop_methods) + j + 1)
            ax.imshow(tonemap(img[win]), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            label = meth if meth == "reference" else f"{meth}\n{relmse(img, ref):.4f}"
            ax.set_title(label, fontsize=6)
            if j == 0:
                ax.set_ylabel(name, fontsize=7)
    fig.suptitle(f"crops at {images[scenes[0]]['show_spp']} spp (titles: whole-image relMSE)", fontsize=8)
    fig.tight_layout()
    return fig


def _cs_sweep(figure: type, results: dict[str, Any], scenes: list[str], key: str, fields: tuple[str, ...]) -> Any:
    """The ``c_s`` sweep per domain: relMSE (``key="cs_relmse"``) or squared bias and variance."""
    rows_n, cols_n = _grid(len(scenes))
    fig = figure(figsize=(4.2 * cols_n, 3.3 * rows_n))
    for i, name in enumerate(scenes):
        ax = fig.add_subplot(rows_n, cols_n, i + 1)
        rows = results["scenes"][name]["c_s_sweep"]
        for dname in DOMAINS:
            dr = [r for r in rows if r["domain"] == dname]
            for fld, ls in zip(fields, ("-", ":")):
                ys = [max(r[fld], 1e-7) for r in dr]
                ax.loglog([r["c_s"] for r in dr], ys, ls, marker="o", ms=3, color=_DOMAIN_COLORS[dname],
                          label=f"{dname} {fld}" if len(fields) > 1 else dname)
        mean_row = next(r for r in rows if r["domain"] == "mean")
        if key == "cs_relmse":
            ax.axhline(mean_row["relmse"], color="black", lw=0.8, ls="--", label="plain mean")
        ax.set_title(f"{name} ({mean_row['spp']} spp)", fontsize=10)
        cs_ticks = sorted({r["c_s"] for r in rows if r["domain"] != "mean"})
        ax.minorticks_off()
        ax.set_xticks(cs_ticks)
        ax.set_xticklabels([f"{c:g}" for c in cs_ticks], fontsize=7)
        ax.set_xlabel("c_s")
        ax.set_ylabel("relMSE" if key == "cs_relmse" else "bias^2 (solid), variance (dotted)")
        ax.grid(True, which="both", alpha=0.3)
        if i == 0:
            ax.legend(fontsize=6)
    fig.tight_layout()
    return fig


def _domain_crops(figure: type, images: dict[str, Any], scenes: list[str]) -> Any:
    """Crops of the domains and ``c_s`` values where the linear domain at ``c_s = 1`` fails worst."""
    cs_all = sorted({float(k.split("c_s=")[1]) for k in images[scenes[0]]["domain_crops"] if "c_s=" in k})
    lo, hi = (1.0 if 1.0 in cs_all else cs_all[0]), cs_all[-1]
    cols = ["reference", "mean", f"linear c_s={lo:g}", f"linear c_s={hi:g}", f"log c_s={lo:g}", f"log c_s={hi:g}",
            f"gamma c_s={lo:g}", f"log robust c_s={lo:g}"]
    fig = figure(figsize=(1.5 * len(cols), 1.65 * len(scenes)))
    for i, name in enumerate(scenes):
        ref = images[name]["reference"]
        crops = images[name]["domain_crops"]
        size = max(16, min(ref.shape[:2]) // 4)
        err = np.mean((crops[f"linear c_s={lo:g}"] - ref) ** 2 / (ref**2 + RELMSE_EPSILON), axis=-1)
        win = error_window(ndimage.gaussian_filter(err, 1.5), size)
        for j, col in enumerate(cols):
            img = ref if col == "reference" else crops[col]
            ax = fig.add_subplot(len(scenes), len(cols), i * len(cols) + j + 1)
            ax.imshow(tonemap(img[win]), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(col if col == "reference" else f"{col}\n{relmse(img[win], ref[win]):.3f}", fontsize=5.5)
            if j == 0:
                ax.set_ylabel(name, fontsize=7)
    fig.suptitle("domain and c_s crops (window where linear c_s=1 errs most; titles: crop relMSE)", fontsize=8)
    fig.tight_layout()
    return fig


def _overhead(figure: type, ov: dict[str, Any]) -> Any:
    """Library time against pixels (left) and against levels (right)."""
    fig = figure(figsize=(8.4, 3.2))
    ax = fig.add_subplot(1, 2, 1)
    px = [r["pixels"] for r in ov["sizes"]]
    for fld, label in (("reconstruct_s", "reconstruct"), ("ask_s", "ask() round"),
                       ("priorities_s", "priorities only")):
        ax.loglog(px, [r[fld] for r in ov["sizes"]], "o-", label=label)
    ax.set_xlabel("pixels")
    ax.set_ylabel("seconds (one core)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    ax = fig.add_subplot(1, 2, 2)
    lv = ov.get("levels", [])
    if lv:
        ax.plot([r["levels"] for r in lv], [r["reconstruct_s"] for r in lv], "o-", label="reconstruct")
        ax.plot([r["levels"] for r in lv], [r["ask_s"] for r in lv], "o-", label="ask() round")
        ax.set_xlabel(f"levels ({lv[0]['size']})")
        ax.set_ylabel("seconds")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
