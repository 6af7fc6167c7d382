"""A time budget: AWR under a deadline (``Sampler.run(seconds=...)``) against uniform sampling in the same time.

Run from the repository root::

    .venv/bin/python benchmarks/bench_deadline.py                  # both renderers, about 15 minutes
    .venv/bin/python benchmarks/bench_deadline.py --renderers tracer --spps 32 64
    .venv/bin/python benchmarks/bench_deadline.py --renderers --hd  # Mitsuba's 1080p Cornell box, 32 spp
    .venv/bin/python benchmarks/bench_deadline.py --costs --hd      # what ranked samples cost, a few minutes

For each scene and uniform sample count ``N`` (32, 64, 128): the uniform render of ``N`` spp is timed (the median
of three renders; Mitsuba 3's own ``mi.render`` through its film, the bundled tracer's uniform request), and
that time ``T`` is the budget of an AWR run: ``AdaptiveSampler(...).run(renderer, seconds=T - t_rec)``, then
``reconstruct``, with ``t_rec`` the median of three default reconstructions of a 2-spp buffer of the scene (the
time the run leaves the reconstruction). Each AWR run is measured whole (the run and the reconstruction) against
``T``; its relMSE and MSE against the reference over the uniform render's (the plain mean of ``N`` spp, what that
time buys without AWR), and both images' mean error against the reference's. Four ways of sizing the rounds
under the deadline, each in the same conditions: the library's (``rounds.ROUND_OVERHEAD``, 0.1), shares of 0.05
and 0.25, and the sampler's default rounds (``round_growth``, no share); ``--repeats`` runs of each (3; seeds
``N + k``), interleaved, their medians (the machine's speed moves a single run's samples by a fifth). "n/a": ``T``
is shorter than ``t_rec`` (the reconstruction alone would not fit).

References: the bundled tracer's cached 4096-spp references (128x128), Mitsuba's 2048-spp film renders cached by
``bench_mitsuba.py`` under ``benchmarks/cache/mitsuba/`` (256x256). ``--renderers synthetic`` runs the synthetic
``edges`` scene against its clean image (the script's test). ``--hd`` adds Mitsuba's Cornell box at 1920x1080
and 32 spp (its 512-spp reference, ``bench_mitsuba.py``'s; section ``deadline_hd``; ``--renderers`` with no
name: it alone). Results: ``benchmarks/results/deadline.json``.

``--costs`` asks what the plan cannot know before the first ranked round (section ``costs``): on each scene the
renderer's time per sample on round 0's uniform request (2 spp) and on the first ranked request of the same total
(the sampler's ``ask`` after round 0), and on that request's counts shuffled over the pixels (the same numbers per
pixel, other pixels: whether it is the pixels the ranking picks that cost more, or the scattered requests); and the
priority analysis' time (``density``), beside ``ask`` and ``tell`` of round 0. Each renders ``--repeats`` times,
interleaved; medians.

``--stages N`` reconstructs with ``stages=N`` instead of the default, in ``t_rec`` and after each run: a cheaper
reconstruction leaves the rounds more of the budget (the trade docs/sampling.md measures at 1080p).
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from awr_denoise import AdaptiveSampler, SampleRequest, metrics, reconstruct, rounds
from awr_denoise.bench import update_section
from awr_denoise.bench.records import results_file
from awr_denoise.metrics import mse, relmse
from awr_denoise.renderers import create_renderer
from awr_denoise.synthetic import make_scene

sys.path.insert(0, str(Path(__file__).resolve().parent))

RESULTS = Path(__file__).resolve().parent / "results" / "deadline.json"
SCENES = {"mitsuba": ("cornell_box", "envmap_sun", "glossy_glass", "dof_checker"),
          "tracer": ("default", "chess_dof", "rolling_balls", "sky_objects", "soft_shadows", "cornell_gi"),
          "synthetic": ("edges",)}
SHAPES = {"mitsuba": (256, 256), "tracer": None, "synthetic": (32, 32)}
SIZINGS = {"library (share 0.1)": None, "share 0.05": 0.05, "share 0.25": 0.25, "default rounds": float("inf")}
"""How the rounds are sized under the deadline: ``rounds.ROUND_OVERHEAD`` as the library has it, or set to these."""
RECONSTRUCTION_SPP = 2
MITSUBA_REFERENCE_SPP = 2048
"""The Mitsuba references' spp: `bench_mitsuba.py`'s, whose cache they share."""
HD = (1080, 1920)
MITSUBA_HD_REFERENCE_SPP = 512
"""The 1080p Cornell box's reference spp (``--hd``): `bench_mitsuba.py`'s."""


@contextlib.contextmanager
def overhead_share(share: float | None) -> Iterator[None]:
    """``rounds.ROUND_OVERHEAD`` set to ``share`` (``None``: the library's; ``inf``: the sampler's own rounds)."""
    saved = rounds.ROUND_OVERHEAD
    rounds.ROUND_OVERHEAD = saved if share is None else share
    try:
        yield
    finally:
        rounds.ROUND_OVERHEAD = saved


class Scene:
    """One scene of one renderer: its renderer, its reference, and a timed uniform render."""

    def __init__(self, renderer: str, name: str, size: int | tuple[int, int] | None) -> None:
        shape = size if isinstance(size, tuple) else (size, size) if size else SHAPES[renderer]
        self.renderer_name, self.name = renderer, name
        self.renderer = create_renderer(renderer, name, shape=shape, seed=0)
        self.shape = tuple(self.renderer.shape)
        if renderer == "mitsuba":
            import bench_mitsuba
            spp = MITSUBA_HD_REFERENCE_SPP if self.shape == HD else MITSUBA_REFERENCE_SPP
            self.reference = bench_mitsuba.reference(self.renderer, name, spp, cache=bench_mitsuba.CACHE,
                                                     regenerate=False)["mean"]
        elif renderer == "tracer":
            from awr_denoise import tracer
            self.reference = np.asarray(tracer.load_reference(name), dtype=np.float64)
        else:
            self.reference = make_scene(name, self.shape).reference()
        for k in range(2):  # compile or load the renderer's kernels before anything is timed
            self.uniform(2, seed=10**6 + k)
            self.renderer(SampleRequest.uniform(self.shape, 2))

    def uniform(self, spp: int, seed: int) -> tuple[np.ndarray, float]:
        """The uniform render of ``spp``: its image and wall seconds (Mitsuba through its own film)."""
        start = time.perf_counter()
        if self.renderer_name == "mitsuba":
            image = np.array(self.renderer._mi.render(self.renderer.scene, spp=spp, seed=seed), dtype=np.float64)
        else:
            self.reseed(seed)
            image = np.asarray(self.renderer(SampleRequest.uniform(self.shape, spp)).mean, dtype=np.float64)
        return image, time.perf_counter() - start

    def reseed(self, seed: int) -> None:
        """Mitsuba's adapter takes a new seed between calls; the tracer and the synthetic renderer keep the one
        they were made with (their random numbers are addressed by pixel and sample index: the AWR runs and the
        uniform renders share them, common random numbers as in ``awr bench``)."""
        if self.renderer_name == "mitsuba":
            self.renderer.seed = seed

    def reconstruction_seconds(self, stages: int | None = None) -> float:
        """The median of three reconstructions of a 2-spp buffer of the scene (``stages``: the default's, or these)."""
        self.reseed(10**6)
        buffer = self.renderer(SampleRequest.uniform(self.shape, RECONSTRUCTION_SPP))
        times = []
        for _ in range(3):
            start = time.perf_counter()
            reconstruct(buffer, **_options(stages))
            times.append(time.perf_counter() - start)
        return statistics.median(times)

    def awr(self, seconds: float, seed: int, share: float | None, stages: int | None = None) -> dict[str, Any]:
        """An AWR run to ``seconds`` with rounds sized by ``share``, then the reconstruction (``stages``)."""
        self.reseed(seed)
        sampler = AdaptiveSampler(self.shape, seed=seed)
        told: list[int] = []
        start = time.perf_counter()
        with overhead_share(share):
            sampler.run(self.renderer, seconds=seconds, callback=lambda request, _: told.append(request.total))
        ran = time.perf_counter() - start
        image = reconstruct(sampler.buffer, **_options(stages))
        total = time.perf_counter() - start
        pixels = self.shape[0] * self.shape[1]
        return {"image": image, "seconds": total, "run_seconds": ran, "spp": sampler.total_samples / pixels,
                "rounds": len(told), "largest_round_spp": max(told) / pixels}


def costs(renderer: str, name: str, size: int | tuple[int, int] | None, repeats: int = 3) -> dict[str, Any]:
    """The renderer's seconds per sample on round 0's request, the first ranked one and its counts shuffled; the
    sampler's ranking (``density``) and round 0's ``ask`` and ``tell`` (``--costs``)."""
    scene = Scene(renderer, name, size)
    scene.reseed(0)
    sampler = AdaptiveSampler(scene.shape, seed=0)
    clock = time.perf_counter
    start = clock()
    first = sampler.ask()
    asked = clock()
    samples = scene.renderer(first)
    rendered = clock()
    sampler.tell(first, samples)
    told = clock()
    rankings = []
    for _ in range(repeats):
        begun = clock()
        sampler.density()
        rankings.append(clock() - begun)
    ranked = sampler.ask(first.total)
    shuffled = SampleRequest(np.random.default_rng(0).permutation(ranked.counts.ravel()).reshape(scene.shape),
                             ranked.first_index, ranked.round, ranked.sampler_id)
    requests = {"uniform": SampleRequest.uniform(scene.shape, sampler.initial_spp), "ranked": ranked,
                "ranked, shuffled": shuffled}
    times: dict[str, list[float]] = {label: [] for label in requests}
    for _ in range(repeats):  # interleaved: the machine's drift falls on each alike
        for label, request in requests.items():
            begun = clock()
            scene.renderer(request)
            times[label].append((clock() - begun) / request.total)
    getattr(scene.renderer, "close", lambda: None)()
    per_sample = {label: statistics.median(t) for label, t in times.items()}
    return {"renderer": renderer, "scene": name, "shape": list(scene.shape), "samples": first.total,
            "per_sample": per_sample, "ranked_over_uniform": per_sample["ranked"] / per_sample["uniform"],
            "shuffled_over_uniform": per_sample["ranked, shuffled"] / per_sample["uniform"],
            "ranking_seconds": statistics.median(rankings), "round0_ask_seconds": asked - start,
            "round0_tell_seconds": told - rendered, "round0_render_seconds": rendered - asked}


def costs_table(rows: list[dict[str, Any]]) -> str:
    """Markdown of ``--costs``: per scene the time per sample, the ratios and the sampler's times."""
    lines = ["| renderer | scene | shape | uniform: us per sample | ranked over uniform | ranked, shuffled over "
             "uniform | ranking s | round 0: ask s, tell s, render s |", "|" + "---|" * 8]
    for r in rows:
        lines.append(f"| {r['renderer']} | {r['scene']} | {r['shape'][1]}x{r['shape'][0]} | "
                     f"{1e6 * r['per_sample']['uniform']:.3f} | {r['ranked_over_uniform']:.2f} | "
                     f"{r['shuffled_over_uniform']:.2f} | {r['ranking_seconds']:.3f} | {r['round0_ask_seconds']:.3f}, "
                     f"{r['round0_tell_seconds']:.3f}, {r['round0_render_seconds']:.3f} |")
    return "\n".join(lines)


def mean_error(image: np.ndarray, reference: np.ndarray) -> float:
    """The image mean's error against the reference's, the largest over the channels, in per cent."""
    return 100 * metrics.mean_error(image, reference)


def _options(stages: int | None) -> dict[str, Any]:
    """``reconstruct``'s options: the default's, or ``stages`` of them (``--stages``)."""
    return {} if stages is None else {"stages": stages}


def measure(renderer: str, name: str, spps: list[int], size: int | tuple[int, int] | None,
            repeats: int = 1, stages: int | None = None) -> list[dict[str, Any]]:
    """Every uniform sample count of one scene: the uniform render's time and error, and each sizing's AWR runs
    (``repeats`` of each, interleaved, seeds ``spp + k``; medians)."""
    scene = Scene(renderer, name, size)
    t_rec = scene.reconstruction_seconds(stages)
    rows = []
    for spp in spps:
        renders = [scene.uniform(spp, seed=1000 * spp + k) for k in range(3)]
        budget = statistics.median(t for _, t in renders)
        image = renders[0][0]
        row: dict[str, Any] = {"renderer": renderer, "scene": name, "shape": list(scene.shape), "uniform_spp": spp,
                               "seconds": budget, "reconstruction_seconds": t_rec, "stages": stages,
                               "uniform_relmse": relmse(image, scene.reference),
                               "uniform_mse": mse(image, scene.reference),
                               "uniform_mean_error": mean_error(image, scene.reference), "awr": {}}
        if budget > t_rec:
            runs: dict[str, list[dict[str, Any]]] = {label: [] for label in SIZINGS}
            for k in range(repeats):  # interleaved: the machine's drift falls on every sizing alike
                for label, share in SIZINGS.items():
                    run = scene.awr(budget - t_rec, seed=spp + k, share=share, stages=stages)
                    result = run.pop("image")
                    runs[label].append({"relmse_ratio": relmse(result, scene.reference) / row["uniform_relmse"],
                                        "mse_ratio": mse(result, scene.reference) / row["uniform_mse"],
                                        "mean_error": mean_error(result, scene.reference), **run})
            row["awr"] = {label: {**{key: statistics.median(r[key] for r in each) for key in each[0]},
                                  "repeats": each} for label, each in runs.items()}
        rows.append(row)
        print(_line(row), flush=True)
    getattr(scene.renderer, "close", lambda: None)()
    return rows


def _line(row: dict[str, Any]) -> str:
    head = f"{row['renderer']} {row['scene']} {row['uniform_spp']} spp in {row['seconds']:.3f} s"
    if not row["awr"]:
        return head + ": n/a"
    return head + "".join(f" | {k}: {v['spp']:.1f} spp, {v['rounds']} rounds, {v['seconds'] / row['seconds']:.2f}T, "
                          f"relMSE {v['relmse_ratio']:.2f}" for k, v in row["awr"].items())


def table(rows: list[dict[str, Any]]) -> str:
    """Markdown: per scene and budget, the uniform render's image-mean error and each sizing's spp, rounds, time over
    the budget, errors over uniform's and image-mean error."""
    labels = list(SIZINGS)
    lines = ["| renderer | scene | uniform spp | seconds | uniform: mean error % | "
             + " | ".join(f"{k}: spp, rounds, time / budget, relMSE / uniform, MSE / uniform, mean error %"
                          for k in labels) + " |",
             "|" + "---|" * (5 + len(labels))]
    for row in rows:
        cells = [(f"{a['spp']:.1f}, {a['rounds']}, {a['seconds'] / row['seconds']:.2f}, {a['relmse_ratio']:.2f}, "
                  f"{a['mse_ratio']:.2f}, {a['mean_error']:.2f}") if (a := row["awr"].get(k)) else "n/a"
                 for k in labels]
        lines.append(f"| {row['renderer']} | {row['scene']} | {row['uniform_spp']} | {row['seconds']:.3f} | "
                     f"{row['uniform_mean_error']:.2f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--renderers", nargs="*", choices=list(SCENES), default=["mitsuba", "tracer"],
                        help="the renderers whose scenes run (none: with --hd, the 1080p box alone)")
    parser.add_argument("--scenes", nargs="+", metavar="NAME", help="only these scenes (default: each renderer's)")
    parser.add_argument("--spps", nargs="+", type=int, default=[32, 64, 128], metavar="N")
    parser.add_argument("--size", type=int, default=None, metavar="PIXELS",
                        help="square images of this side (default: 256x256 for Mitsuba, the tracer's 128x128)")
    parser.add_argument("--hd", action="store_true",
                        help="also Mitsuba's Cornell box at 1920x1080 at 32 spp (section deadline_hd)")
    parser.add_argument("--repeats", type=int, default=3, metavar="N",
                        help="AWR runs of each sizing per budget (seeds spp + k), interleaved; medians (default 3)")
    parser.add_argument("--stages", type=int, choices=[1, 2, 3], default=None,
                        help="reconstruct with this many stages instead of the default (its time then reserved)")
    parser.add_argument("--costs", action="store_true",
                        help="instead: what ranked samples and the ranking cost against round 0's (section costs)")
    parser.add_argument("--output", type=results_file, default=RESULTS)
    args = parser.parse_args(argv)
    if not 1 <= args.repeats <= 99:
        parser.error("--repeats: 1 to 99")
    if any(n < 1 for n in args.spps):
        parser.error("--spps: whole numbers of at least 1")
    if args.size is not None and args.size < 8:
        parser.error("--size: at least 8")
    if args.size is not None and "tracer" in args.renderers:
        parser.error("--size: the tracer's references are 128x128; not with --renderers tracer")
    known = [n for r in args.renderers for n in SCENES[r]]
    unknown = [n for n in args.scenes or () if n not in known]
    if unknown:  # a misspelt name measured nothing (an empty table, or a refused empty section after the work)
        parser.error(f"--scenes: {', '.join(unknown)} not among the scenes of {', '.join(args.renderers) or 'none'}: "
                     f"{', '.join(known)}")
    command = "benchmarks/bench_deadline.py " + " ".join(sys.argv[1:] if argv is None else argv)
    if not args.renderers and not args.hd:
        parser.error("--renderers: none given and no --hd: nothing to run")
    if args.costs:
        jobs = [(r, n, args.size) for r in args.renderers for n in SCENES[r] if args.scenes is None or n in args.scenes]
        jobs += [("mitsuba", "cornell_box", HD)] if args.hd else []
        found = [costs(*job, repeats=args.repeats) for job in jobs]
        update_section(args.output, "costs", found, command)
        print(costs_table(found))
        return 0
    rows = []
    for renderer in args.renderers:
        for name in SCENES[renderer]:
            if args.scenes is None or name in args.scenes:
                rows += measure(renderer, name, args.spps, args.size, args.repeats, args.stages)
    if rows:
        update_section(args.output, "deadline", rows, command)
    if args.hd:
        hd = measure("mitsuba", "cornell_box", [32], HD, args.repeats, args.stages)
        update_section(args.output, "deadline_hd", hd, command)
        rows += hd
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
