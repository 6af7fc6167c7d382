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
