"""The benchmark's page, ``docs/benchmarks.md``, written from the raw results.

One function per section of the page; each returns its lines. The text between the notes
markers is read from the existing page and kept, so a reading of the numbers written by hand
survives a re-run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .analysis import MEAN_CHANGE_BOUND, row_at
from .config import DOMAINS, METHODS

__all__ = ["write_markdown", "kept_notes", "format_number", "NOTES_BEGIN", "NOTES_END"]

NOTES_BEGIN = "<!-- notes: kept across runs -->"
NOTES_END = "<!-- /notes -->"


def format_number(v: Any, digits: int = 4) -> str:
    """A table cell: ``digits`` significant digits, scientific when very large or small.

    ``None`` is ``-``, booleans are ``yes``/``no``, infinity ``inf`` and NaN ``n/a``.

    Examples
    --------
    >>> format_number(0.012345), format_number(12345.0), format_number(None), format_number(True)
    ('0.01235', '1.234e+04', '-', 'yes')
    """
    if v is None:
        return "-"
    if isinstance(v, str):
        return v
    if isinstance(v, bool):
        return "yes" if v else "no"
    v = float(v)
    if not np.isfinite(v):
        return "inf" if v > 0 else "n/a"
    if v == 0:
        return "0"
    if abs(v) >= 1000 or abs(v) < 10 ** -(digits - 1):
        return f"{v:.{digits - 1}e}"
    return f"{v:.{digits}g}"


_fmt = format_number


def _eq(row: dict[str, Any] | None) -> str:
    """The equal-error spp cell (``*`` when extrapolated)."""
    if row is None:
        return "-"
    v = row["equal_error_spp"]
    if not np.isfinite(v):
        return "below floor"
    return f"{v:.0f}" + ("*" if row["equal_error_extrapolated"] else "")


def _mean_cells(row: dict[str, Any]) -> str:
    """The image mean's error against the reference and its change from the method's own samples, in per
    cent (``-`` in results measured before they were recorded)."""
    cells = [f"{100 * row[k]:.2f}%" if k in row else "-" for k in ("mean_error", "mean_change")]
    return ", ".join(cells)


def _shown_path(path: Path) -> str:
    """``path`` relative to the working directory when inside it (no machine paths in the page)."""
    try:
        return path.resolve().relative_to(Path.cwd().resolve()).as_posix()
    except ValueError:
        return path.name


def kept_notes(path: Path) -> str:
    """The hand-written notes of the existing page at ``path`` (empty when none).

    Raises
    ------
    ValueError
        The page is not UTF-8 text, or its notes are not between one pair of markers, :data:`NOTES_BEGIN` before
        :data:`NOTES_END` (its notes cannot be kept).
    """
    if path.is_file():
        try:
            old = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise ValueError(f"{path}: not a text page, so its notes cannot be kept; move it away") from None
        begins, ends = old.count(NOTES_BEGIN), old.count(NOTES_END)
        if begins or ends:
            # An opening marker alone, the two reversed or a second pair: the notes were dropped, exit 0 (an attack
            # pass).
            if begins != 1 or ends != 1 or old.index(NOTES_END) < old.index(NOTES_BEGIN):
                raise ValueError(f"{path}: its notes are not between one {NOTES_BEGIN} and one {NOTES_END} after it "
                                 f"({begins} and {ends} found), so they cannot be kept; mend the page or move it away")
            return old[old.index(NOTES_BEGIN) + len(NOTES_BEGIN):old.index(NOTES_END)].strip("\n")
    return ""


def write_markdown(results: dict[str, Any], figures: dict[str, str], path: Path,
                   results_path: str | Path | None, *, out: Path | None = None) -> None:
    """Write the benchmark's page to ``path``, keeping the notes of the page already there.

    Parameters
    ----------
    results
        The raw results of :func:`awr_denoise.bench.run_benchmark`.
    figures
        File names of the figures drawn (in ``img/`` beside the page), by key; a figure not
        drawn is left out of the page.
    path
        The page (``benchmarks.md``); its directory is created.
    results_path
        Where the raw numbers were written (named in the page), or ``None``.
    out
        Where to write the page instead of ``path`` (a temporary, moved into place with the
        run's other outputs); the notes are read from ``path``.
    """
    scenes = list(results["scenes"])
    methods = [m for m in METHODS if all(m in results["scenes"][s]["methods"] for s in scenes)]
    lines = _intro(results, scenes, results_path, kept_notes(path))
    lines += _reproduce()
    lines += _references(results, scenes)
    lines += _headline(results, figures, scenes, methods)
    lines += _goals(results, scenes)
    lines += _all_metrics(results, scenes, methods)
    lines += _equal_time(results, figures, scenes, methods)
    lines += _density(results, figures)
    lines += _smoothing(results, figures, scenes)
    lines += _other_defaults(results, scenes)
    lines += _overhead(results, figures)
    lines += _mitsuba(results)
    target = path if out is None else Path(out)
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text("\n".join(lines).rstrip() + "\n", encoding="utf-8")


def _intro(results: dict[str, Any], scenes: list[str], results_path: str | Path | None, notes: str) -> list[str]:
    meta = results["meta"]
    cfg = meta["config"]
    cmd = "awr bench" + (" --quick" if meta["mode"] == "quick" else "")
    raw = "not written" if results_path is None else f"`{_shown_path(Path(results_path))}`"
    shape = results["scenes"][scenes[0]]["shape"]
    lines = [
        "# Benchmarks: the speed/accuracy trade on the bundled path-traced scenes\n",
        f"Generated by `{cmd}` (mode **{meta['mode']}**, {meta['date']}, Python {meta['python']}, "
        f"{meta['processor']}); the run took **{meta['run_seconds'] / 60:.1f} minutes**"
        # The machine as measured: every user's page said "this shared 2-core machine" (an attack pass).
        + (f" on {meta['cpus']} CPUs" if meta.get("cpus") else "")
        + f". Raw numbers: {raw}. Every figure on this page is written by that command; the text between the notes "
        "markers is kept across runs.\n",
        f"Scenes: {', '.join(scenes)}, at {shape[1]}x{shape[0]} pixels. relMSE = mean of `(x - r)^2 / (r^2 + "
        f"{meta['relmse_epsilon']:g})` over pixels and channels; the image mean's error is the largest channel's "
        "relative difference of means; SSIM on the sRGB-tonemapped image. All methods "
        f"use render seed {cfg['seed']} (the tracer's addressable random numbers make this common random "
        "numbers: method differences are not seed noise). Reconstruction is `reconstruct(buffer)` with the "
        "library defaults unless stated.\n",
        f"Open Image Denoise: {meta['oidn']}.\n",
    ]
    if notes:
        lines += [NOTES_BEGIN, notes, NOTES_END + "\n"]
    else:
        lines.append(NOTES_BEGIN + "\n" + NOTES_END + "\n")
    return lines


def _reproduce() -> list[str]:
    return [
        "## Reproduce\n",
        "```\npython -m awr_denoise.tracer.reference all --spp 4096   # references (once; about 20 min)\n"
        "awr bench --quick                                        # a few minutes\n"
        "awr bench                                                # the full run\n```\n",
        "`awr bench` runs `python -m awr_denoise.bench` with the command line's handling of signals and "
        "errors (one line, no partial output: docs/cli.md); it needs the `tracer` and `bench` extras, and "
        "`oidn` for the Open Image Denoise peer.\n",
        "`--scenes a b` restricts the scenes, `--output-dir DIR` writes the page and figures elsewhere, "
        "`--reference-spp N` re-renders (and caches) any reference below N spp with the tracer's "
        "`load_reference`.\n",
    ]


def _references(results: dict[str, Any], scenes: list[str]) -> list[str]:
    cfg = results["meta"]["config"]
    lines = [
        "## References and their noise floor\n",
        "A reference rendered with a finite number of samples has its own variance, which adds a constant "
        "`f` to every relMSE measured against it: `E[relMSE] = true relMSE + f`. `f` is estimated by fitting "
        "`a / N + f` to the uniform Monte Carlo curve (its true relMSE falls exactly as `1 / N`); the bound "
        "is what an independent-sampler reference with that spp would have (the references use the tracer's "
        "Owen-scrambled Sobol' sampler, which converges faster). Equal-error spp below are computed on "
        "floor-corrected errors; an error within the floor cannot be resolved.\n",
        "| scene | reference spp | sampler | floor `f` (fit) | bound (independent) | uniform relMSE at 1 spp (`a`) | "
        f"uniform relMSE at {cfg['uniform_max_spp']} spp | floor share there |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name in scenes:
        ref = results["scenes"][name]["reference"]
        last = results["scenes"][name]["uniform_curve"][-1]
        lines.append(f"| {name} | {ref['spp']} | {ref['sampler']} | {_fmt(ref['floor_fit'])} | "
                     f"{_fmt(ref.get('floor_bound_independent'))} | {_fmt(ref['uniform_relmse_1spp_fit'])} | "
                     f"{_fmt(last['relmse'])} | {last['relmse'] and ref['floor_fit'] / last['relmse']:.0%} |")
    lines.append("")
    return lines


def _headline(results: dict[str, Any], figures: dict[str, str], scenes: list[str], methods: list[str]) -> list[str]:
    head = results["summary"]["headline_spp"]
    cfg = results["meta"]["config"]
    lines = [
        f"## Headline: equal samples at {head} spp\n",
        f"relMSE at {head} spp average, and in parentheses the equal-error spp: the uniform Monte Carlo "
        "sample count with the same (floor-corrected) relMSE, interpolated in log-log on the uniform curve "
        f"(`*`: outside the rendered 4-{cfg['uniform_max_spp']} spp, extrapolated with the fitted `a / N`).\n",
        "| scene | " + " | ".join(methods) + " | uniform at 512 spp |",
        "|---" * (len(methods) + 2) + "|",
    ]
    for name in scenes:
        m = results["scenes"][name]["methods"]
        cells = []
        for meth in methods:
            r = row_at(m[meth], head)
            cells.append("-" if r is None else f"{_fmt(r['relmse'])} ({_eq(r)})")
        u512 = row_at(results["scenes"][name]["uniform_curve"], 512)
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {_fmt(u512['relmse']) if u512 else '-'} |")
    lines.append("")
    if "error_vs_spp" in figures:
        lines.append(f"![relMSE against spp](img/{figures['error_vs_spp']})\n")
    if "crops" in figures:
        lines.append(f"![crops](img/{figures['crops']})\n")
    return lines


def _goals(results: dict[str, Any], scenes: list[str]) -> list[str]:
    summary = results["summary"]
    head = summary["headline_spp"]
    lines = [
        "## Goals\n",
        "| scene | AWR relMSE / uniform at equal spp | AWR at 32 spp <= uniform at 512 spp | AWR better than "
        "skimage | overhead / render time: CPU / wall / 1080p est. |",
        "|---|---|---|---|---|",
    ]
    for name in scenes:
        s = summary["scenes"][name]
        share_big = s.get("overhead_share_1080p_estimate")
        share_cpu = s.get("overhead_share_cpu")
        lines.append(
            f"| {name} | {_fmt(s.get('awr_vs_uniform_same_spp'), 3)} | {_fmt(s.get('awr_at_or_below_uniform_512'))} | "
            f"{_fmt(s.get('awr_better_than_skimage'))} | "
            f"{'-' if share_cpu is None else format(share_cpu, '.1%')} / "
            f"{'-' if s.get('overhead_share') is None else format(s['overhead_share'], '.1%')} / "
            f"{'-' if share_big is None else format(share_big, '.1%')} |")
    lines.append("")
    lines.append(
        "Overhead share: (time in `ask`/`tell` over all rounds + one `reconstruct`) / tracer time, for AWR "
        f"sampling to {head} spp, as CPU time / wall time / estimated at 1080p. The tracer runs on "
        f"{results['meta']['config']['threads']} threads, the library on one; CPU time is the robust figure on a "
        "shared machine. The 1080p estimate scales the tracer's CPU time with the pixel count and takes the "
        "`ask()` and `reconstruct` times measured at 1080p (section Overhead), with the same number of rounds.\n")
    seeds = results["meta"]["config"].get("flag_seeds", 1)
    noise = summary.get("flags_not_confirmed", [])
    if summary["flags"]:
        lines += ["### Flags: a default worse than the plain mean\n",
                  "**These are bugs by the project's own rule.**"
                  + (f" Each was checked over {seeds} seeds and its error summed over them is still above the "
                     "plain mean's." if seeds > 1 else "") + "\n"]
        lines += [f"- {f}" for f in summary["flags"]]
        lines.append("")
    elif noise:
        lines.append(f"No flag stands: every method with library defaults that was worse than the plain mean on the main "
                     f"render is below it in the error summed over {seeds} seeds (next section).\n")
    else:
        lines.append("No method with library defaults was worse than the plain mean on any scene at any spp, in relMSE "
                     f"or in MSE, nor moved its samples' image mean by more than {100 * MEAN_CHANGE_BOUND:g}%.\n")
    if noise:
        lines += ["### Flags not confirmed over seeds\n",
                  f"Worse than the plain mean on the main render (seed {results['meta']['config']['seed']}), but not "
                  f"in the error summed over {seeds} seeds (the same method and plain mean rendered again with the "
                  "next seeds): where a few pixels hold the squared error, one render's error moves by tens of "
                  "percent from seed to seed. The per-seed spread is given: a default above the plain mean on "
                  "some seeds still loses there on those renders.\n"]
        lines += [f"- {f}" for f in noise]
        lines.append("")
    return lines


def _all_metrics(results: dict[str, Any], scenes: list[str], methods: list[str]) -> list[str]:
    lines = ["## All metrics\n",
             "Image mean: its error against the reference's, and its change from the plain mean of the method's "
             "own samples (each the largest channel's relative difference, `awr_denoise.metrics.mean_error`; "
             f"a default that changes it by more than {100 * MEAN_CHANGE_BOUND:g}% is flagged).\n"]
    for name in scenes:
        m = results["scenes"][name]["methods"]
        lines += [f"### {name}\n",
                  "| method | spp | relMSE | MSE | image mean: error, change | PSNR (dB) | SSIM | equal-error spp "
                  "| CPU time (s) | wall time (s) |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for meth in methods:
            for r in m[meth]:
                lines.append(f"| {meth} | {r['spp']} | {_fmt(r['relmse'])} | {_fmt(r['mse'])} | {_mean_cells(r)} | "
                             f"{r['psnr']:.2f} | {r['ssim']:.4f} | {_eq(r)} | {r['total_cpu_s']:.2f} | "
                             f"{r['total_s']:.2f} |")
        lines.append("")
    return lines


def _equal_time(results: dict[str, Any], figures: dict[str, str], scenes: list[str], methods: list[str]
                ) -> list[str]:
    head = results["summary"]["headline_spp"]
    others = [x for x in methods if x != "uniform"]
    lines = [
        "## Equal time\n",
        "Time of the whole loop: tracer, `ask`/`tell` of every round and one reconstruction (or peer "
        "denoiser), as process CPU time (the tracer's two threads both count): wall time on this shared "
        "machine depends on what else runs, CPU time much less. Wall times are in the JSON and the tables "
        f"above. Below: relMSE at {head} spp and, in parentheses, the ratio to uniform Monte Carlo's relMSE at "
        "the same CPU time (interpolated in log-log on the uniform curve; below 1 wins at equal time).\n",
        "| scene | " + " | ".join(others) + " |",
        "|---" * len(methods) + "|",
    ]
    for name in scenes:
        et = results["summary"]["scenes"][name].get("equal_time", {})
        cells = [f"{_fmt(et[x]['relmse'])} ({et[x]['ratio']:.2f})" if x in et else "-" for x in others]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append("")
    if "error_vs_time" in figures:
        lines.append(f"![relMSE against time](img/{figures['error_vs_time']})\n")
    return lines


def _density(results: dict[str, Any], figures: dict[str, str]) -> list[str]:
    lines = ["## Where the samples went\n",
             f"Samples per pixel relative to the mean, at {results['summary']['headline_spp']} spp, for the adaptive "
             "samplers.\n"]
    if "density" in figures:
        lines.append(f"![sample density](img/{figures['density']})\n")
    return lines


def _smoothing(results: dict[str, Any], figures: dict[str, str], scenes: list[str]) -> list[str]:
    cfg = results["meta"]["config"]
    lines = [
        "## Smoothing constant and domain\n",
        f"Uniform buffers at {cfg['sweep_spp']} spp for {cfg['sweep_seeds']} seeds, reconstructed with "
        "`reconstruct(buffer, c_s=..., domain=...)`. relMSE is the mean over seeds; variance is the "
        "per-pixel variance across seeds (relMSE-weighted); squared bias is the error of the seed-mean "
        "with the variance share and the reference floor removed (it can come out slightly negative where "
        "the bias is below what the seeds resolve).\n",
        "| scene | plain mean | " + " | ".join(f"best c_s {d}" for d in DOMAINS) + " | "
        + " | ".join(f"{d} at c_s=1" for d in DOMAINS) + " |",
        "|---" * (2 + 2 * len(DOMAINS)) + "|",
    ]
    for name in scenes:
        rows = results["scenes"][name]["c_s_sweep"]
        mean_row = next(r for r in rows if r["domain"] == "mean")
        best = []
        at1 = []
        for d in DOMAINS:
            dr = [r for r in rows if r["domain"] == d]
            b = min(dr, key=lambda r: r["relmse"])
            best.append(f"{b['c_s']:g} ({_fmt(b['relmse'])})")
            one = next((r for r in dr if r["c_s"] == 1.0), None)
            at1.append(_fmt(one["relmse"]) if one else "-")
        lines.append(f"| {name} | {_fmt(mean_row['relmse'])} | " + " | ".join(best) + " | " + " | ".join(at1) + " |")
    lines.append("")
    lines.append("Squared bias / variance at each c_s (log domain, the default):\n")
    cs_vals = cfg["c_s_values"]
    lines += ["| scene | " + " | ".join(f"c_s={c:g}" for c in cs_vals) + " |", "|---" * (1 + len(cs_vals)) + "|"]
    for name in scenes:
        rows = [r for r in results["scenes"][name]["c_s_sweep"] if r["domain"] == "log"]
        lines.append(f"| {name} | "
                     + " | ".join(f"{_fmt(r['bias2'], 2)} / {_fmt(r['variance'], 2)}" for r in rows) + " |")
    lines.append("")
    for key, caption in (("cs_relmse", "relMSE against c_s"), ("cs_bias_variance", "bias and variance"),
                         ("domain_crops", "domain crops")):
        if key in figures:
            lines.append(f"![{caption}](img/{figures[key]})\n")
    return lines


def _other_defaults(results: dict[str, Any], scenes: list[str]) -> list[str]:
    swept = [s for s in scenes if "defaults_sweep" in results["scenes"][s]]
    if not swept:
        return []
    first = results["scenes"][swept[0]]["defaults_sweep"]
    lines = [
        "## The other defaults\n",
        f"relMSE at {first[0]['spp']} spp, mean over {results['meta']['config']['defaults_seeds']} seeds, one "
        "setting changed at a time (reconstruction settings on uniform buffers; sampler settings with "
        "`AdaptiveSampler` and the default reconstruction; in parentheses the sampler's CPU time as a share of "
        "the tracer's). **Bold**: the library default.\n",
        "| setting | " + " | ".join(scenes) + " |",
        "|---" * (1 + len(scenes)) + "|",
    ]
    for group, value, default in [(r["group"], r["value"], r["default"]) for r in first]:
        label = f"{group} = {value}"
        label = f"**{label}**" if default else label
        cells = []
        for s in scenes:
            r = next((x for x in results["scenes"][s].get("defaults_sweep", [])
                      if x["group"] == group and x["value"] == value), None)
            cell = _fmt(r["relmse"]) if r else "-"
            if r and r.get("sampler_cpu_share") is not None:
                cell += f" ({r['sampler_cpu_share']:.0%})"
            cells.append(cell)
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append("")
    return lines


def _overhead(results: dict[str, Any], figures: dict[str, str]) -> list[str]:
    ov = results.get("overhead", {})
    if not ov.get("sizes"):
        return []
    lines = [
        "## Overhead\n",
        "One core, median of repeated runs after a warm-up that builds the cached wavelet operators; a "
        "synthetic 4-spp buffer. `ask()` is one adaptive round (priorities + allocation).\n",
        "| size | reconstruct (s) | per megapixel (s) | ask() round (s) | per megapixel (s) | priorities only (s) |",
        "|---|---|---|---|---|---|",
    ]
    for r in ov["sizes"]:
        lines.append(f"| {r['size']} | {r['reconstruct_s']:.3f} | {r['reconstruct_s_per_mp']:.3f} | "
                     f"{r['ask_s']:.3f} | {r['ask_s_per_mp']:.3f} | {r['priorities_s']:.3f} |")
    lines.append("")
    if ov.get("levels"):
        lines += [f"Against the number of levels at {ov['levels'][0]['size']}:\n",
                  "| levels | reconstruct (s) | ask() round (s) |", "|---|---|---|"]
        lines += [f"| {r['levels']} | {r['reconstruct_s']:.3f} | {r['ask_s']:.3f} |" for r in ov["levels"]]
        lines.append("")
    if "overhead" in figures:
        lines.append(f"![overhead](img/{figures['overhead']})\n")
    return lines



def _mitsuba(results: dict[str, Any]) -> list[str]:
    mi = results.get("mitsuba")
    if mi is None:
        return []
    lines = ["## Mitsuba 3 scenes\n",
             "The same library defaults on scenes of a renderer the project did not write, through the Mitsuba "
             "adapter ([integrate_mitsuba.md](integrate_mitsuba.md)). `uniform`/`awr`: the plain mean of "
             "uniform/AWR sampling; `+awr`: the default reconstruction of that buffer. MSE is given as a ratio "
             "to the plain mean of the same samples, the image mean as its error against the reference's.\n"]
    if not mi.get("scenes"):
        return lines + [f"Not measured: {mi.get('status', 'unknown')}.\n"]
    worse = []
    for name, scene in mi["scenes"].items():
        h, w = scene["shape"]
        ref = scene["reference"]
        lines += [f"**{name}** ({w}x{h}, reference: {ref['spp']} spp of the adapter)\n",
                  "| spp | relMSE uniform | uniform+awr | awr | awr+awr | MSE / plain (uniform+awr, awr+awr) "
                  "| image mean error (uniform+awr, awr+awr) |",
                  "|---|---|---|---|---|---|---|"]
        by = {m: {r["spp"]: r for r in rows} for m, rows in scene["methods"].items()}
        for spp in sorted(by["uniform"]):
            u, ua, a, aa = (by[m][spp] for m in ("uniform", "uniform+awr", "awr", "awr+awr"))
            lines.append(f"| {spp} | {_fmt(u['relmse'])} | {_fmt(ua['relmse'])} | {_fmt(a['relmse'])} | "
                         f"{_fmt(aa['relmse'])} | {ua['mse'] / u['mse']:.2f}, {aa['mse'] / a['mse']:.2f} | "
                         f"{100 * ua['mean_error']:+.2f}%, {100 * aa['mean_error']:+.2f}% |")
            for plain, denoised in ((u, ua), (a, aa)):
                # The image mean's change from the samples', from the two errors against the reference.
                moved = abs((1 + denoised["mean_error"]) / (1 + plain["mean_error"]) - 1) > MEAN_CHANGE_BOUND
                if denoised["relmse"] > plain["relmse"] or denoised["mse"] > plain["mse"] or moved:
                    worse.append(f"{name} at {spp} spp")
        lines.append("")
    lines.append("Reconstructions worse than the plain mean of their own samples (relMSE or MSE), or that move "
                 f"its image mean by more than {100 * MEAN_CHANGE_BOUND:g}%: "
                 + (", ".join(dict.fromkeys(worse)) if worse else "none") + ".\n")
    return lines
