"""From measured errors to the benchmark's findings: noise floor, equal-error spp, summary.

A reference rendered with finitely many samples adds its own variance ``f`` to every relMSE
measured against it; :func:`fit_noise_floor` estimates it from the uniform Monte Carlo curve
and :func:`equal_error_spp` converts an error into the uniform sample count that reaches it
(the paper's headline is "AWR at 32 spp is near Monte Carlo at 512 spp").
:func:`summarize` derives the headline numbers, the goals and the flags that
``docs/benchmarks.md`` reports.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .._typing import FloatArray
from ..metrics import mean_error, mse, psnr, relmse, ssim
from .config import DOMAINS, BenchmarkConfig

__all__ = ["image_metrics", "fit_noise_floor", "equal_error_spp", "correct_for_noise_floor", "headline_spp",
           "row_at", "summarize", "flag_candidates", "FLAG_METHODS", "MEAN_CHANGE_BOUND"]


def image_metrics(image: FloatArray, reference: FloatArray) -> dict[str, float]:
    """relMSE, MSE, the image mean's error, PSNR and SSIM of ``image`` against ``reference``
    (:mod:`awr_denoise.metrics`).

    Examples
    --------
    >>> m = image_metrics(np.full((4, 4, 3), 0.5), np.full((4, 4, 3), 0.4))
    >>> round(m["mse"], 6), round(m["relmse"], 6), round(m["mean_error"], 6)
    (0.01, 0.058824, 0.25)
    """
    return {"relmse": relmse(image, reference), "mse": mse(image, reference),
            "mean_error": mean_error(image, reference), "psnr": psnr(image, reference), "ssim": ssim(image, reference)}


def fit_noise_floor(spps: Sequence[float], errors: Sequence[float]) -> tuple[float, float]:
    """Fit ``error(N) = a / N + f`` to a uniform Monte Carlo curve; returns ``(a, f)``.

    The error of an unbiased estimate against a noisy reference is its own variance (``a / N``)
    plus the reference's (``f``, the noise floor, independent of ``N``). Least squares in
    relative terms; ``f`` is clipped to ``[0, 0.95 min(error)]``.

    Parameters
    ----------
    spps
        Sample counts of the curve.
    errors
        relMSE at each count.

    Returns
    -------
    tuple of float
        ``(a, f)``: the relMSE at one sample per pixel without the floor, and the floor.

    Examples
    --------
    >>> n = np.array([4.0, 8.0, 16.0, 32.0, 64.0])
    >>> a, f = fit_noise_floor(n, 0.2 / n + 1e-4)
    >>> round(a, 6), round(f, 8)
    (0.2, 0.0001)
    """
    n = np.asarray(spps, dtype=np.float64)
    e = np.asarray(errors, dtype=np.float64)
    design = np.stack([1.0 / (n * e), 1.0 / e], axis=1)
    (a, f), *_ = np.linalg.lstsq(design, np.ones_like(e), rcond=None)
    f = float(np.clip(f, 0.0, 0.95 * e.min()))
    above = e > f
    # Refit a with f fixed, as the geometric mean of (e - f) N (relative least squares in log terms).
    a = float(np.exp(np.mean(np.log((e[above] - f) * n[above])))) if above.any() else 0.0
    return a, f


def equal_error_spp(error: float, spps: Sequence[float], uniform_errors: Sequence[float],
                    slope_a: float) -> tuple[float, bool]:
    """Uniform Monte Carlo spp reaching ``error`` (all floor-corrected); returns ``(spp, extrapolated)``.

    Interpolated in log-log on the uniform curve; outside its range the fitted ``a / N`` law is
    used and ``extrapolated`` is True. An error at or below zero (under the reference's noise
    floor) gives ``inf``.

    Parameters
    ----------
    error
        The error to match.
    spps, uniform_errors
        The uniform curve.
    slope_a
        ``a`` of :func:`fit_noise_floor`, for extrapolation.

    Returns
    -------
    tuple
        ``(spp, extrapolated)``.

    Examples
    --------
    >>> n = np.array([4.0, 8.0, 16.0, 32.0])
    >>> spp, extrapolated = equal_error_spp(0.4 / 11, n, 0.4 / n, 0.4)
    >>> round(spp, 6), extrapolated
    (11.0, False)
    >>> equal_error_spp(0.4 / 100, n, 0.4 / n, 0.4)
    (100.0, True)
    """
    if not error > 0:
        return float("inf"), True
    n = np.asarray(spps, dtype=np.float64)
    u = np.minimum.accumulate(np.asarray(uniform_errors, dtype=np.float64))  # monotone for interp
    ok = u > 0
    n, u = n[ok], u[ok]
    if n.size >= 2 and u[-1] <= error <= u[0]:
        lu, ln = np.log(u[::-1]), np.log(n[::-1])
        return float(np.exp(np.interp(np.log(error), lu, ln))), False
    return float(slope_a / error) if slope_a > 0 else float("nan"), True


def correct_for_noise_floor(uniform_curve: list[dict[str, Any]],
                            methods: dict[str, list[dict[str, Any]]]) -> tuple[float, float]:
    """Fit the reference's noise floor and add floor-corrected errors and equal-error spp to the rows.

    Every row of ``uniform_curve`` gains ``relmse_corrected``; every row of ``methods`` gains
    ``relmse_corrected``, ``equal_error_spp``, ``equal_error_extrapolated`` and
    ``equal_error_spp_uncorrected`` (against the raw curve).

    Parameters
    ----------
    uniform_curve
        Rows with ``spp`` and ``relmse`` of uniform Monte Carlo, in increasing spp.
    methods
        Rows with ``relmse`` of each method, by method.

    Returns
    -------
    tuple of float
        ``(a, f)`` of :func:`fit_noise_floor`.
    """
    c_spps = [row["spp"] for row in uniform_curve]
    c_err = [row["relmse"] for row in uniform_curve]
    slope_a, floor = fit_noise_floor(c_spps, c_err)
    corrected_curve = [e - floor for e in c_err]
    for row, corr in zip(uniform_curve, corrected_curve):
        row["relmse_corrected"] = corr
    for rows in methods.values():
        for row in rows:
            row["relmse_corrected"] = row["relmse"] - floor
            eq, extrapolated = equal_error_spp(row["relmse_corrected"], c_spps, corrected_curve, slope_a)
            row["equal_error_spp"] = eq
            row["equal_error_extrapolated"] = extrapolated
            eq_raw, _ = equal_error_spp(row["relmse"], c_spps, c_err, slope_a)
            row["equal_error_spp_uncorrected"] = eq_raw
    return slope_a, floor


def headline_spp(spps: Sequence[int]) -> int:
    """The sample count of the headline comparison: 32 when measured, else the middle one.

    Examples
    --------
    >>> headline_spp([4, 8, 32]), headline_spp([4, 8, 16])
    (32, 8)
    """
    return 32 if 32 in spps else spps[len(spps) // 2]


def row_at(rows: list[dict[str, Any]], spp: int) -> dict[str, Any] | None:
    """The row measured at ``spp``, or ``None``.

    Examples
    --------
    >>> row_at([{"spp": 4, "relmse": 0.1}, {"spp": 8, "relmse": 0.05}], 8)
    {'spp': 8, 'relmse': 0.05}
    """
    return next((r for r in rows if r["spp"] == spp), None)


def summarize(results: dict[str, Any], config: BenchmarkConfig) -> dict[str, Any]:
    """Headline numbers, goals and flags computed from the raw results.

    Parameters
    ----------
    results
        The raw results of :func:`awr_denoise.bench.run_benchmark` (``scenes`` and
        ``overhead``).
    config
        The configuration they were measured with.

    Returns
    -------
    dict
        ``headline_spp``, per-scene ``scenes`` entries (relMSE and equal-error spp at the
        headline spp, goals, overhead shares, equal-time ratios), ``flags`` (a reconstruction
        with defaults worse than the plain mean: a bug by the project's rule; checked over seeds
        where ``results`` holds ``flag_checks``, :mod:`~awr_denoise.bench.flagcheck`),
        ``flags_not_confirmed`` (one render above the plain mean, the error summed over the seeds
        below it) and ``best_c_s``.
    """
    head_spp = headline_spp(sorted(config.spps))
    out: dict[str, Any] = {"headline_spp": head_spp, "scenes": {}, "flags": [], "flags_not_confirmed": []}
    big = next((r for r in results.get("overhead", {}).get("sizes", []) if r["size"] == "1080p"), None)
    for name, sc in results["scenes"].items():
        out["scenes"][name] = _scene_summary(sc, head_spp, big)
        flags, noise = _flags(name, sc, results.get("flag_checks", []))
        out["flags"].extend(flags)
        out["flags_not_confirmed"].extend(noise)
    out["best_c_s"] = _best_c_s(results)
    return out


def _scene_summary(sc: dict[str, Any], head_spp: int, big: dict[str, Any] | None) -> dict[str, Any]:
    """One scene's entry of :func:`summarize`; ``big`` is the overhead row at 1080p, if measured."""
    row = {meth: row_at(rows, head_spp) for meth, rows in sc["methods"].items()}
    u512 = {r["spp"]: r for r in sc["uniform_curve"]}.get(512)
    entry: dict[str, Any] = {"relmse": {k: v["relmse"] for k, v in row.items() if v},
                             "equal_error_spp": {k: v["equal_error_spp"] for k, v in row.items() if v},
                             "uniform_512_relmse": None if u512 is None else u512["relmse"]}
    awr = row.get("awr+awr")
    if awr is not None:
        entry["awr_vs_uniform_same_spp"] = awr["relmse"] / row["uniform"]["relmse"]
        if u512 is not None:
            entry["awr_at_or_below_uniform_512"] = awr["relmse"] <= u512["relmse"]
        sk = row.get("uniform+skimage")
        if sk is not None:
            entry["awr_better_than_skimage"] = awr["relmse"] < sk["relmse"]
        entry.update(_overhead_shares(awr, sc["shape"], big))
    entry["equal_time"] = _equal_time(sc["uniform_curve"], row)
    return entry


def _overhead_shares(awr: dict[str, Any], shape: Sequence[int], big: dict[str, Any] | None) -> dict[str, Any]:
    """Library time over tracer time for the AWR loop: wall, CPU and estimated at 1080p."""
    out: dict[str, Any] = {}
    render = awr["render_s"]
    out["overhead_share"] = (awr["sampler_s"] + awr["reconstruct_s"]) / render if render > 0 else None
    render_cpu = awr["render_cpu_s"]
    out["overhead_share_cpu"] = ((awr["sampler_cpu_s"] + awr["reconstruct_cpu_s"]) / render_cpu
                                 if render_cpu > 0 else None)
    out["overhead_split_s"] = {"render": render, "sampler": awr["sampler_s"],
                               "reconstruct": awr["reconstruct_s"], "rounds": awr["rounds"]}
    if big is not None and render > 0:
        # The same loop at 1080p: tracer time scales with pixels, ask() and reconstruct as measured.
        pixels = shape[0] * shape[1]
        render_big = render_cpu * big["pixels"] / pixels
        out["overhead_share_1080p_estimate"] = (awr["rounds"] * big["ask_s"] + big["reconstruct_s"]) / render_big
    return out


def _equal_time(uniform_curve: list[dict[str, Any]], row: dict[str, dict[str, Any] | None]) -> dict[str, Any]:
    """Each method's relMSE against uniform MC's at the same CPU time, interpolated in log-log."""
    t_u = np.array([r["total_cpu_s"] for r in uniform_curve])
    e_u = np.array([r["relmse"] for r in uniform_curve])
    order = np.argsort(t_u)
    t_u, e_u = t_u[order], e_u[order]
    out = {}
    for meth, r in row.items():
        if r is None or meth == "uniform" or not (t_u[0] <= r["total_cpu_s"] <= t_u[-1]) or r["total_cpu_s"] <= 0:
            continue
        at = float(np.exp(np.interp(np.log(r["total_cpu_s"]), np.log(t_u), np.log(e_u))))
        out[meth] = {"cpu_s": r["total_cpu_s"], "relmse": r["relmse"], "uniform_relmse": at,
                     "ratio": r["relmse"] / at}
    return out


FLAG_METHODS = ("uniform+awr", "awr+awr", "awr-levels+awr", "awr-gain+awr", "variance+awr")
"""The methods whose defaults a flag judges against the plain mean at equal samples."""

MEAN_CHANGE_BOUND = 0.005
"""The most a default reconstruction may move the image mean of its own samples (the largest channel's
relative change, :func:`~awr_denoise.metrics.mean_error`): the reconstruction issue's bound of 0.5%."""


def _violations(sc: dict[str, Any]) -> list[tuple[str, int, str, float, float]]:
    """``(method, spp, metric, value, plain mean's value)`` wherever a method is above the plain mean."""
    out = []
    m = sc["methods"]
    for meth in FLAG_METHODS:
        for r in m.get(meth, []):
            u = row_at(m["uniform"], r["spp"])
            for key in ("relmse", "mse"):
                if u is not None and r[key] > u[key]:
                    out.append((meth, r["spp"], key, r[key], u[key]))
    return out


def flag_candidates(results: dict[str, Any]) -> list[tuple[str, str, int]]:
    """Every (scene, method, spp) that :func:`summarize` flags, once each (in relMSE, MSE or both).

    Examples
    --------
    >>> row = lambda spp, e: {"spp": spp, "relmse": e, "mse": e}
    >>> scene = {"methods": {"uniform": [row(4, 1.0)], "awr+awr": [row(4, 2.0)], "uniform+awr": [row(4, 0.5)]}}
    >>> flag_candidates({"scenes": {"s": scene}})
    [('s', 'awr+awr', 4)]
    """
    seen: list[tuple[str, str, int]] = []
    for name, sc in results["scenes"].items():
        for meth, spp, *_ in _violations(sc):
            if (name, meth, spp) not in seen:
                seen.append((name, meth, spp))
    return seen


def _flags(name: str, sc: dict[str, Any], checks: list[dict[str, Any]]) -> tuple[list[str], list[str]]:
    """``(flags, not confirmed)``: methods with library defaults worse than the plain mean at equal
    samples, in relMSE or in MSE; a flag checked over seeds (:mod:`~awr_denoise.bench.flagcheck`)
    stands when its error summed over them is above the plain mean's, and is not confirmed otherwise.
    A default that moves its own samples' image mean by more than :data:`MEAN_CHANGE_BOUND` is flagged
    on that render alone."""
    flags, noise = [], []
    labels = {"relmse": "relMSE", "mse": "MSE"}
    for meth, spp, key, value, plain in _violations(sc):
        text = f"{name}: {meth} at {spp} spp is worse than the plain mean ({labels[key]} {value:.4g} > {plain:.4g})"
        check = next((c for c in checks if (c["scene"], c["method"], c["spp"]) == (name, meth, spp)), None)
        if check is None or len(check["seeds"]) < 2:
            flags.append(text)
            continue
        ratios = [a / b for a, b in zip(check[key], check[f"plain_{key}"])]
        pooled = sum(check[key]) / sum(check[f"plain_{key}"])
        text += (f"; over seeds {check['seeds'][0]}-{check['seeds'][-1]} the summed {labels[key]} is "
                 f"{pooled:.2f}x the plain mean's, above it on {sum(r > 1 for r in ratios)} of {len(ratios)} "
                 f"(per seed {min(ratios):.2f}-{max(ratios):.2f}x)")
        (flags if pooled > 1 else noise).append(text)
    # The image mean is judged on the render itself, not over seeds: a default that moves its own samples'
    # mean by more than the bound has changed that render's exposure, whatever another render does.
    for meth in FLAG_METHODS:
        for r in sc["methods"].get(meth, []):
            if r.get("mean_change", 0.0) > MEAN_CHANGE_BOUND:
                flags.append(f"{name}: {meth} at {r['spp']} spp moves the image mean of its samples by "
                             f"{100 * r['mean_change']:.2f}% (more than {100 * MEAN_CHANGE_BOUND:g}%)")
    for r in sc.get("c_s_sweep", []):
        if r["domain"] == "log" and r["c_s"] == 1.0 and r.get("worse_than_mean"):
            flags.append(f"{name}: the default reconstruction (log, c_s=1) is worse than the plain mean "
                         f"in the c_s sweep at {r['spp']} spp")
    return flags, noise


def _best_c_s(results: dict[str, Any]) -> dict[str, dict[str, float]]:
    """The c_s of least relMSE per domain, per scene."""
    best: dict[str, dict[str, float]] = {}
    for name, sc in results["scenes"].items():
        best[name] = {}
        for dname in DOMAINS:
            rows = [r for r in sc.get("c_s_sweep", []) if r["domain"] == dname]
            if rows:
                best[name][dname] = min(rows, key=lambda r: r["relmse"])["c_s"]
    return best
