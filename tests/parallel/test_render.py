"""Tiled rendering (awr_denoise.parallel.render) against serial renders, bit for bit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from awr_denoise import AdaptiveSampler, SampleRequest, UniformSampler
from awr_denoise.parallel import (
    RendererSpec,
    TiledRenderer,
    get_executor,
    render_tiled,
)
from awr_denoise.synthetic import SyntheticRenderer, make_scene
from parallel_helpers import (
    assert_same_buffer,
    serial_render,
)


def test_render_tiled_equals_the_serial_render_bitwise():
    shape = (70, 90)
    spec = RendererSpec.synthetic("fireflies", shape, seed=5)
    expected = serial_render(spec, shape, 12)
    assert_same_buffer(render_tiled(spec, AdaptiveSampler(shape, seed=2), total_spp=12, tile=32), expected)
    assert_same_buffer(render_tiled(spec, AdaptiveSampler(shape, seed=2), total_spp=12, tile=(70, 13)), expected)


def test_render_tiled_differs_when_the_seed_differs():
    shape = (40, 40)
    expected = serial_render(RendererSpec.synthetic("edges", shape, seed=5), shape, 6)
    other = render_tiled(RendererSpec.synthetic("edges", shape, seed=6), AdaptiveSampler(shape, seed=2),
                         total_spp=6, tile=16)
    assert not np.array_equal(other.mean, expected.mean)


@dataclasses.dataclass(frozen=True)
class RequestOnlyFactory:
    """Builds a renderer that offers only ``__call__(request)`` (no per-sample entry point)."""

    spec: RendererSpec

    def __call__(self):
        inner = self.spec()
        return lambda request: inner(request)


def test_render_tiled_works_with_any_renderer():
    shape = (48, 40)
    spec = RendererSpec.synthetic("gradient", shape, seed=1)
    expected = UniformSampler(shape, seed=1).run(spec(), 6)
    with get_executor("threads", workers=2) as executor:
        tiled = render_tiled(RequestOnlyFactory(spec), UniformSampler(shape, seed=1), total_spp=6, tile=16,
                             executor=executor)
    assert_same_buffer(tiled, expected)


def test_tiled_renderer_builds_one_renderer_per_worker_thread():
    built = []

    def factory():
        built.append(1)
        return RendererSpec.synthetic("edges", (32, 32))()

    renderer = TiledRenderer(factory, tile=8)  # no executor: tiles in this thread, one after the other
    request = SampleRequest.uniform((32, 32), 2)
    assert_same_buffer(renderer(request), RendererSpec.synthetic("edges", (32, 32))()(request))
    renderer(request)
    assert len(built) == 1


def test_tiled_renderer_checks_its_arguments():
    with pytest.raises(TypeError, match="renderer_factory"):
        TiledRenderer(SyntheticRenderer(make_scene("edges", (8, 8))).scene)
    with pytest.raises(ValueError, match="tile"):
        TiledRenderer(RendererSpec.synthetic("edges", (8, 8)), tile=0)
    with pytest.raises(TypeError, match="executor"):
        TiledRenderer(RendererSpec.synthetic("edges", (8, 8)), executor="dask")
    with pytest.raises(ValueError, match="shape"):
        RendererSpec("synthetic", "edges")
    with pytest.raises(ValueError, match="kind"):
        RendererSpec("oidn", "edges", (8, 8))
    # A scene name the renderer does not bundle failed every tile on its worker, one by one.
    with pytest.raises(ValueError, match=r"^scene: 'edgez' is neither a scene the synthetic renderer bundles "
                                         r"\(gradient, edges, .*\) nor a file$"):
        RendererSpec.synthetic("edgez", (8, 8))


def test_factories_that_cannot_be_pickled_get_their_own_renderers():
    """An unpicklable factory (a lambda, a closure) was cached under its id, which Python gives to the
    next object at the same address: frames 1-5 of a loop rendered with frame 0's seed, a second
    scene came back as the first (a red-team pass)."""
    from concurrent.futures import ThreadPoolExecutor

    shape = (16, 16)
    scenes = {name: make_scene(name, shape) for name in ("edges", "gradient", "fireflies")}

    def frame(name, seed, pool):  # a new lambda per frame, freed when the frame is done
        factory = lambda: SyntheticRenderer(scenes[name], seed=seed)  # noqa: E731
        return render_tiled(factory, UniformSampler(shape), total_spp=2, tile=8, executor=pool)

    with ThreadPoolExecutor(1) as pool:  # one long-lived worker thread: its cache lives across frames
        for seed, name in enumerate(["gradient", "gradient", "edges", "fireflies", "gradient", "edges"]):
            tiled = frame(name, seed, pool)
            assert_same_buffer(tiled, UniformSampler(shape).run(SyntheticRenderer(scenes[name], seed=seed), 2))


def test_a_renderer_of_another_size_is_refused_not_cropped():
    """A 64x64 scene with a 32x32 sampler: ``sampler.run`` refuses it, ``render_tiled`` returned the
    top-left quarter of the image (a red-team pass)."""
    spec = RendererSpec.synthetic("edges", (64, 64))

    class Own:  # a renderer of requests only, rendering its own 64x64 film whatever it is asked
        def __call__(self, request):
            return spec()(SampleRequest.uniform((64, 64), 1))

    for factory in (spec, Own):  # a SampleTracer, and a plain renderer (its result was cropped too)
        with pytest.raises(ValueError, match=r"request: shape \(32, 32\) does not match the renderer's \(64, 64\)"):
            render_tiled(factory, UniformSampler((32, 32)), total_spp=2, tile=16)


def test_a_failed_tile_cancels_the_rest_of_the_round():
    """A tile's error (or Ctrl-C) reached the caller only after every other tile of the round had
    rendered (64 tiles of a slow renderer: 16 s instead of 1; a red-team pass)."""
    import threading

    calls = []
    lock = threading.Lock()

    class Failing:
        def __call__(self, request):
            with lock:
                calls.append(1)
                if len(calls) == 2:
                    raise RuntimeError("tile failed")
            return RendererSpec.synthetic("edges", (64, 64))()(request)

    with get_executor("threads", workers=1) as executor:
        with pytest.raises(RuntimeError, match="tile failed"):
            TiledRenderer(Failing, tile=8, executor=executor)(SampleRequest.uniform((64, 64), 1))
    assert len(calls) < 64 // 2


def test_no_renderer_outlives_its_tiled_renderer_and_the_cache_lets_go(monkeypatch):
    """Tracers kept by the calling thread's cache held their process pools for good (8 child processes
    after six TiledRenderer calls without an executor): without one a TiledRenderer builds its own
    renderer; one pushed out of a worker's cache is let go, not closed (a factory may return a
    renderer its caller still uses: closing it broke the caller's later calls, a review)."""
    import gc
    import weakref

    from awr_denoise.parallel import render as render_module

    built = []

    @dataclasses.dataclass(frozen=True)
    class Recording:
        seed: int

        def __call__(self):
            inner = RendererSpec.synthetic("edges", (16, 16), seed=self.seed)()
            built.append(weakref.ref(inner))
            return inner

    monkeypatch.setattr(render_module, "_RENDERER_CACHE_SIZE", 1)
    request = SampleRequest.uniform((16, 16), 1)
    before = dict(getattr(render_module._worker_state, "renderers", {}))
    TiledRenderer(Recording(9), tile=8)(request)
    assert dict(getattr(render_module._worker_state, "renderers", {})) == before  # no cache without an executor
    shared = RendererSpec.synthetic("edges", (16, 16))()
    with get_executor("threads", workers=1) as executor:
        for seed in range(3):
            TiledRenderer(Recording(seed), tile=8, executor=executor)(request)
            TiledRenderer(lambda: shared, tile=8, executor=executor)(request)  # noqa: B023 - the caller's own
        gc.collect()
        assert all(ref() is None for ref in built)  # each pushed out by the shared one, and let go
    assert_same_buffer(shared(request), RendererSpec.synthetic("edges", (16, 16))()(request))  # still usable



def test_a_plain_renderer_sees_the_requests_round_and_sampler():
    """A renderer that is not a SampleTracer got every tile's request as round 0 of sampler 0, whatever
    the sampler's round (a renderer may read them, as the file protocol's batches copy the round)."""
    seen = []

    class Reading:
        def __call__(self, request):
            seen.append((request.round, request.sampler_id))
            return RendererSpec.synthetic("edges", (16, 16))()(request)

    sampler = UniformSampler((16, 16))
    own = sampler.ask().sampler_id  # round 0's request, planned here: the sampler's id
    render_tiled(Reading, sampler, total_spp=6, tile=8, executor=None)
    assert own != 0 and {s for _, s in seen} == {own}
    assert sorted({r for r, _ in seen}) == list(range(sampler.round)) and sampler.round > 1


def test_a_tile_is_traced_in_parts_with_the_same_statistics(monkeypatch):
    """A tile's samples were held at once (a 128x128 tile at 1024 spp: 2 GB); it is traced in parts of
    at most ``MAX_PART_SAMPLES`` (bands of rows: the serial render bit for bit)."""
    from awr_denoise.parallel import render as render_module

    shape = (70, 90)
    spec = RendererSpec.synthetic("fireflies", shape, seed=5)
    expected = UniformSampler(shape, seed=2).run(spec(), 12)
    sizes = []
    trace = SyntheticRenderer.trace_samples
    monkeypatch.setattr(SyntheticRenderer, "trace_samples",
                        lambda self, rows, *rest: sizes.append(rows.size) or trace(self, rows, *rest))
    monkeypatch.setattr(render_module, "MAX_PART_SAMPLES", 1000)
    assert_same_buffer(render_tiled(spec, UniformSampler(shape, seed=2), total_spp=12, tile=32), expected)
    assert sizes and max(sizes) <= 1000 and sum(sizes) == 12 * 70 * 90


def test_a_scene_file_is_named_absolutely_and_held_to_its_bytes(tmp_path, monkeypatch):
    """On a Dask cluster a relative scene file was read in each worker's own folder, and a worker kept the renderer of
    a file edited since: images of another scene, exit 0 (an attack pass). A spec names the file absolutely with the
    digest of its bytes; a worker refuses other bytes at that path, and an edited file is a new spec, so a new
    renderer (the cache is keyed by the pickled spec)."""
    pytest.importorskip("embreex")
    from pathlib import Path

    scenes = Path(__file__).resolve().parents[2] / "data" / "scenes"
    (tmp_path / "here").mkdir()
    (tmp_path / "there").mkdir()
    (tmp_path / "here" / "scene.json").write_bytes((scenes / "cornell_gi.json").read_bytes())
    (tmp_path / "there" / "scene.json").write_bytes((scenes / "default.json").read_bytes())
    monkeypatch.chdir(tmp_path / "here")
    spec = RendererSpec.tracer("scene.json", width=8, height=8, threads=1)
    assert spec.scene == str(tmp_path / "here" / "scene.json") and spec.digest is not None
    assert RendererSpec.tracer(Path("scene.json"), width=8, height=8, threads=1) == spec  # a Path alike
    monkeypatch.chdir(tmp_path / "there")  # a worker in another folder reads the same file
    expected = spec()(SampleRequest.uniform((8, 8), 2))
    (tmp_path / "here" / "scene.json").write_bytes((scenes / "default.json").read_bytes())
    with pytest.raises(ValueError, match="scene: .*scene.json here holds other bytes than the file"):
        spec()
    (tmp_path / "there" / "cornell_gi").write_bytes(b"")  # a bundled scene's name stays a name
    assert RendererSpec.tracer("cornell_gi", width=8, height=8).scene == "cornell_gi"
    edited = RendererSpec.tracer(str(tmp_path / "here" / "scene.json"), width=8, height=8, threads=1)
    assert edited != spec and edited.digest != spec.digest
    assert not np.array_equal(edited()(SampleRequest.uniform((8, 8), 2)).mean, expected.mean)
