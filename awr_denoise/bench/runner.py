"""The benchmark run: every bundled scene measured, then the JSON, the figures and the page written."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
from .._progress import tqdm

from .._typing import FloatArray
from ..buffers import SampleBuffer
from ..io.atomic import STAGING_NAME, OutputSet, check_writable, folders_made
from ..metrics import RELMSE_EPSILON, mean_error, relmse
from ..reconstruct import reconstruct
from ..sampling import UniformSampler
from .analysis import correct_for_noise_floor, flag_candidates, headline_spp, image_metrics, summarize
from .config import METHODS, BenchmarkConfig
from .figures import FIGURE_FILES, require_matplotlib, write_figures
from .flagcheck import ADAPTIVE_METHODS, check_flags
from .measure import Timing, run_progressive, timed
from .mitsuba import default_reference_dir, mitsuba_benchmark, mitsuba_scene_names
from .overhead import measure_overhead
from .peers import oidn_available, oidn_denoise, require_skimage, skimage_denoise
from .records import machine_info, write_json
from .rendering import make_tracer, reference_image, tracer_module
from .report import kept_notes, write_markdown
from .sweeps import cs_sweep, defaults_sweep

__all__ = ["run_benchmark", "scene_benchmark"]

Tick = Callable[[str], None]


def run_benchmark(config: BenchmarkConfig | None = None, *, output_dir: str | Path | None = "docs",
                  results_path: str | Path | None = None, plots: bool = True, progress: bool = True,
                  mode_name: str | None = None) -> dict[str, Any]:
    """Run the benchmark; write the JSON, the figures and ``benchmarks.md``; return the results.

    Parameters
    ----------
    config
        What to measure; default :class:`BenchmarkConfig` (the full run).
    output_dir
        Directory of ``benchmarks.md`` and of the figures (in its ``img/``); ``None`` writes no
        document and no figure.
    results_path
        Where the raw numbers go as JSON; default ``benchmarks/results/quality.json`` beside
        ``output_dir``'s parent; ``None`` together with ``output_dir=None`` writes nothing.
    plots
        Draw the PNG figures (needs matplotlib).
    progress
        Show a progress bar (tqdm) on stderr.
    mode_name
        Label of the run in the outputs (``"full"``, ``"quick"``, ...).

    Returns
    -------
    dict
        The raw results (the JSON's content).

    Raises
    ------
    ValueError
        An unknown or repeated scene name, or an output that cannot be written (checked before
        anything is measured; nothing is written then).
    ImportError
        A needed extra (``tracer``, ``bench``) is missing; the message says what to install.
    """
    config = config or BenchmarkConfig()
    scenes = _checked_scenes(config)
    mitsuba_scene_names(config)  # unknown names are refused even when Mitsuba is not run
    require_skimage()
    if plots and output_dir is not None:
        require_matplotlib()  # fail early, with the install hint
    use_oidn = bool(config.oidn) and oidn_available()
    out_dir = None if output_dir is None else Path(output_dir)
    derived = results_path is None and out_dir is not None  # beside the output folder: named by it
    if derived:
        results_path = out_dir.resolve().parent / "benchmarks" / "results" / "quality.json"
    _check_outputs(out_dir, None if results_path is None else Path(results_path), plots, derived=derived)
    _refuse_outputs_onto_references(out_dir, None if results_path is None else Path(results_path), scenes, config)

    stages = len(scenes) * (5 + int(config.defaults_sweep)) + len(config.overhead_sizes) + 1 + \
        (len(mitsuba_scene_names(config)) if config.mitsuba else 0)
    bar = tqdm(total=stages, desc="awr bench", unit="stage", file=sys.stderr) if progress else None

    def tick(label: str) -> None:
        if bar is not None:
            bar.set_postfix_str(label, refresh=False)
            bar.update(1)

    # Warm up the peers once (imports, device creation) so their first timing is not inflated.
    warm = np.random.default_rng(0).uniform(0.0, 1.0, (16, 16, 3))
    skimage_denoise(warm)
    if use_oidn:
        oidn_denoise(warm)
    started = time.perf_counter()
    results: dict[str, Any] = {"meta": _meta(config, mode_name, use_oidn), "scenes": {}}
    all_images: dict[str, Any] = {}
    try:
        for name in scenes:
            results["scenes"][name], all_images[name] = scene_benchmark(name, config, use_oidn, tick)
        if bar is not None and config.flag_seeds > 1:
            bar.total += len(flag_candidates(results))  # known only now: the checks of what was flagged
        results["flag_checks"] = check_flags(results, config, tick) if config.flag_seeds > 1 else []
        results["overhead"] = measure_overhead(config, tick) if config.overhead_sizes else {"sizes": [], "levels": []}
        results["mitsuba"] = mitsuba_benchmark(config, tick) if config.mitsuba else {"status": "not asked for",
                                                                                      "scenes": {}}
    finally:
        if bar is not None:
            bar.close()
    results["summary"] = summarize(results, config)
    results["meta"]["run_seconds"] = time.perf_counter() - started
    # The JSON, the figures and the page: all of them or none (an interrupt leaves the old ones).
    # The folders it makes for them too: an interrupt while they are written left them behind, empty.
    folders = ([Path(results_path).parent] if results_path is not None else []) + \
        ([out_dir / "img" if plots else out_dir] if out_dir is not None else [])
    with folders_made(*folders), OutputSet(overwrite=True) as outputs:
        if results_path is not None:
            write_json(outputs.add(results_path), results)
        if out_dir is not None:
            figures = write_figures(results, all_images, out_dir / "img", place=outputs.add) if plots else {}
            write_markdown(results, figures, out_dir / "benchmarks.md", results_path,
                           out=outputs.add(out_dir / "benchmarks.md"))
        outputs.commit()
    return results


def _check_outputs(out_dir: Path | None, results_path: Path | None, plots: bool, *, derived: bool = False) -> None:
    """Refuse, before anything is measured, outputs the run could not write at its end (``derived``: the
    results' path was made from the output folder's, which a refusal then names)."""
    checks = []
    if results_path is not None:
        if results_path.suffix.lower() != ".json":
            raise ValueError(f"results_path / --results: {results_path} is not a .json file")
        checks.append(("output_dir / --output-dir" if derived else "results_path / --results", results_path))
    if out_dir is not None:
        checks.append(("output_dir / --output-dir", out_dir / "benchmarks.md"))
        if plots:  # every figure: a FIFO or a folder at any of their names was found after the run
            checks += [("output_dir / --output-dir", out_dir / "img" / name) for name in FIGURE_FILES.values()]
    for param, path in checks:
        folder = path.parent
        while not folder.exists():  # created at the end: its nearest existing parent must take it
            if os.path.lexists(folder):
                raise ValueError(f"{param}: {folder} is a broken symbolic link")
            if STAGING_NAME.match(folder.name):  # refused at the commit, after the run, as an existing one is
                raise ValueError(f"{param}: {folder} would be named as awr's staging folders, which later writes "
                                 "remove as leftovers; write elsewhere")
            folder = folder.parent
        try:
            if not folder.is_dir():
                raise ValueError(f"{folder} is not a folder")
            # The target itself when its folder exists (a regular file, replaced), else a probe there.
            check_writable(path if folder == path.parent else folder / ".awr-bench", overwrite=True)
        except (ValueError, FileNotFoundError) as exc:
            raise ValueError(f"{param}: {exc}") from None
    if out_dir is not None:
        kept_notes(out_dir / "benchmarks.md")  # an unreadable page is refused now, not after the run


def _refuse_outputs_onto_references(out_dir: Path | None, results_path: Path | None, scenes: list[str],
                                    config: BenchmarkConfig) -> None:
    """Refuse an output that is a reference the run reads, by a link or another name: ``--results q.json``
    linked to ``data/references/default.exr`` replaced that reference with the JSON."""
    outputs = [] if results_path is None else [("results_path / --results", results_path)]
    if out_dir is not None:
        outputs.append(("output_dir / --output-dir", out_dir / "benchmarks.md"))
        outputs += [("output_dir / --output-dir", p) for p in sorted((out_dir / "img").glob("bench_*.png"))]
    tracer = tracer_module()
    references = [tracer.reference_path(name) for name in scenes]
    if config.mitsuba:  # asked for only then: a run without Mitsuba needs no folder of its references
        mitsuba_dir = Path(config.mitsuba_reference_dir or default_reference_dir())
        references += sorted(mitsuba_dir.glob("*.npy")) if mitsuba_dir.is_dir() else []
    known = {}
    for path in references:
        if path.is_file():
            st = path.stat()
            known[path.resolve()] = known[(st.st_dev, st.st_ino)] = path
    for param, path in outputs:
        st = path.stat() if path.exists() else None
        source = known.get(path.resolve()) or (None if st is None else known.get((st.st_dev, st.st_ino)))
        if source is not None:
            raise ValueError(f"{param}: {path} is the reference {source}, which the run reads; write elsewhere")


def _checked_scenes(config: BenchmarkConfig) -> list[str]:
    """The scenes to run; a :class:`ValueError` naming an unknown one."""
    tracer = tracer_module()
    scenes = list(config.scenes) if config.scenes else tracer.list_scenes()
    for k, name in enumerate(scenes):
        if name not in tracer.list_scenes():
            raise ValueError(f"scenes: {name!r} is not one of {', '.join(tracer.list_scenes())}")
        if name in scenes[:k]:
            raise ValueError(f"scenes: {name!r} is given twice")
    return scenes


def _meta(config: BenchmarkConfig, mode_name: str | None, use_oidn: bool) -> dict[str, Any]:
    """The run's description at its start: mode, configuration, date, machine and OIDN status."""
    machine = machine_info()
    return {"mode": mode_name or "custom", "config": asdict(config),
            "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "python": machine["python"], "platform": machine["platform"], "processor": machine["processor"],
            "cpus": machine["cpus"],
            "oidn": "used" if use_oidn else ("not installed (pyoidn did not import)" if config.oidn else "disabled"),
            "relmse_epsilon": RELMSE_EPSILON}


# ---------------------------------------------------------------------------------------- one scene
def _time_fields(timing: Timing, seconds: tuple[float, float]) -> dict[str, float]:
    """A result row's timings: the loop's, one reconstruction's ``(wall, CPU)`` and their totals."""
    return {**timing.fields(), "reconstruct_s": seconds[0], "reconstruct_cpu_s": seconds[1],
            "total_s": timing.render + timing.sampler + seconds[0],
            "total_cpu_s": timing.render_cpu + timing.sampler_cpu + seconds[1]}


def scene_benchmark(name: str, config: BenchmarkConfig, use_oidn: bool, tick: Tick
                    ) -> tuple[dict[str, Any], dict[str, Any]]:
    """All measurements of one scene: (JSON-ready results, images kept for the figures).

    Parameters
    ----------
    name
        Bundled scene name.
    config
        What to measure.
    use_oidn
        Include the Open Image Denoise peer.
    tick
        Called with a label after each stage (progress).

    Returns
    -------
    tuple
        The scene's results (``shape``, ``dimension``, ``reference``, ``uniform_curve``,
        ``methods``, ``c_s_sweep`` and maybe ``defaults_sweep``) and the images the figures
        show (``reference``, ``show_spp``, ``crops``, ``density``, ``domain_crops``).
    """
    scene = tracer_module().load_scene(name, width=config.width, height=config.height)
    reference, ref_info = reference_image(name, scene, config)
    tick(f"{name}: reference")
    weight = 1.0 / (reference**2 + RELMSE_EPSILON)
    spps = sorted(set(int(s) for s in config.spps))
    images: dict[str, Any] = {"reference": reference, "show_spp": headline_spp(spps), "crops": {}, "density": {}}
    methods: dict[str, list[dict[str, Any]]] = {m: [] for m in METHODS if m != "uniform+oidn" or use_oidn}

    uniform_curve, uniform_buffers = _uniform_stage(scene, reference, spps, config, use_oidn, methods, images)
    tick(f"{name}: uniform to {uniform_curve[-1]['spp']} spp")
    for method, sampler_cls in ADAPTIVE_METHODS.items():
        _adaptive_stage(sampler_cls, scene, reference, spps, config, methods[method], images, method)
        tick(f"{name}: {method}")

    # Reference noise floor, from the uniform curve, and an upper bound from the per-sample variance.
    last = uniform_buffers.get(spps[-1])
    if last is not None and ref_info["spp"]:
        per_sample = last.estimated_variance()
        ref_info["floor_bound_independent"] = float(np.mean(per_sample / ref_info["spp"] * weight))
    slope_a, floor = correct_for_noise_floor(uniform_curve, methods)
    ref_info["floor_fit"] = floor
    ref_info["uniform_relmse_1spp_fit"] = slope_a

    result: dict[str, Any] = {"shape": [scene.height, scene.width], "dimension": getattr(scene, "dimension", None),
                              "reference": ref_info, "uniform_curve": uniform_curve, "methods": methods}
    result["c_s_sweep"], images["domain_crops"] = cs_sweep(scene, reference, weight, floor, config,
                                                           uniform_buffers.get(config.sweep_spp))
    tick(f"{name}: c_s sweep")
    if config.defaults_sweep:
        result["defaults_sweep"] = defaults_sweep(scene, reference, config, uniform_buffers.get(config.defaults_spp))
        tick(f"{name}: defaults sweep")
    return result, images


def _uniform_stage(scene: Any, reference: FloatArray, spps: list[int], config: BenchmarkConfig, use_oidn: bool,
                   methods: dict[str, list[dict[str, Any]]], images: dict[str, Any]
                   ) -> tuple[list[dict[str, Any]], dict[int, SampleBuffer]]:
    """Uniform Monte Carlo in one progressive render (nested sample indices) up to ``uniform_max_spp``.

    Every snapshot adds a row to the uniform curve; at the measured ``spps`` the plain mean,
    AWR's reconstruction and the peers add rows to ``methods``. Returns the curve and the
    buffers at ``spps``.
    """
    curve_spps = sorted(set([int(2**k) for k in range(2, int(np.log2(max(config.uniform_max_spp, 4))) + 1)]
                            + spps))
    uniform_curve: list[dict[str, Any]] = []
    uniform_buffers: dict[int, SampleBuffer] = {}

    def snapshot(spp: int, buffer: SampleBuffer, timing: Timing) -> None:
        mean = np.array(buffer.mean)
        uniform_curve.append({"spp": spp, **image_metrics(mean, reference), **_time_fields(timing, (0.0, 0.0))})
        if spp not in spps:
            return
        uniform_buffers[spp] = buffer
        outs = {"uniform": (mean, (0.0, 0.0))}
        outs["uniform+awr"] = timed(lambda: reconstruct(buffer))
        outs["uniform+skimage"] = timed(lambda: skimage_denoise(mean))
        if use_oidn:
            outs["uniform+oidn"] = timed(lambda: oidn_denoise(mean))
        for method, (image, seconds) in outs.items():
            methods[method].append({"spp": spp, **image_metrics(image, reference), **_time_fields(timing, seconds),
                                    "mean_change": mean_error(image, mean)})
            if spp == images["show_spp"]:
                images["crops"][method] = image

    renderer = make_tracer(scene, config.seed, config.threads)
    try:
        run_progressive(UniformSampler((scene.height, scene.width), seed=config.seed), renderer, curve_spps, snapshot)
    finally:
        renderer.close()
    return uniform_curve, uniform_buffers


def _adaptive_stage(sampler_cls: type, scene: Any, reference: FloatArray, spps: list[int], config: BenchmarkConfig,
                    rows: list[dict[str, Any]], images: dict[str, Any], method: str) -> None:
    """An adaptive sampler and AWR's reconstruction at each of ``spps``: rows, crops and sample density."""

    def snapshot(spp: int, buffer: SampleBuffer, timing: Timing) -> None:
        image, seconds = timed(lambda: reconstruct(buffer))
        rows.append({"spp": spp, **image_metrics(image, reference), **_time_fields(timing, seconds),
                     "mean_change": mean_error(image, buffer.mean),
                     "plain_mean_relmse": relmse(buffer.mean, reference),
                     "max_pixel_spp": int(buffer.count.max()),
                     "min_pixel_spp": int(buffer.count.min())})
        if spp == images["show_spp"]:
            images["crops"][method] = image
            images["density"][method] = buffer.count / buffer.count.mean()

    renderer = make_tracer(scene, config.seed, config.threads)
    try:
        run_progressive(sampler_cls((scene.height, scene.width), seed=config.seed), renderer, spps, snapshot)
    finally:
        renderer.close()
