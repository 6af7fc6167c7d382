"""The renderer registry: names, factories, and the scenes each renderer bundles."""

from __future__ import annotations

import pytest

from awr_denoise import renderers
from awr_denoise.renderers import (create_renderer, register_renderer, renderer_features, renderer_names,
                                   renderer_scenes)
from awr_denoise.synthetic import SCENES, SyntheticRenderer, make_scene


def _edges(scene, *, shape=None, seed=0):
    return SyntheticRenderer(make_scene("edges", shape or (8, 8)), seed=seed)


@pytest.fixture
def registered(monkeypatch):
    monkeypatch.setattr(renderers, "_registered", {})
    register_renderer("test-edges", _edges)
    return "test-edges"


def test_built_ins_are_named():
    assert {"mitsuba", "synthetic", "tracer"} <= set(renderer_names())


def test_a_registered_factory_builds_and_cannot_be_replaced_by_accident(registered):
    assert registered in renderer_names()
    assert create_renderer(registered, None, shape=(4, 6)).shape == (4, 6)
    with pytest.raises(ValueError, match="registered already"):
        register_renderer(registered, _edges)
    register_renderer(registered, _edges, replace=True)


def test_scenes_come_from_the_module_that_declares_the_factory():
    assert renderer_scenes("synthetic") == list(SCENES)
    # The tracer's factory is written in a submodule and re-exported by the package, which lists
    # the scenes: the declared module is the one asked.
    pytest.importorskip("embreex")
    from awr_denoise import tracer

    assert tracer.create_renderer.__module__ != "awr_denoise.tracer"
    assert renderer_scenes("tracer") == tracer.list_scenes()


def test_a_renderer_without_list_scenes_bundles_none(registered):
    # This test module defines no list_scenes(): the registered factory's module is asked.
    assert renderer_scenes(registered) == []


def test_unknown_names_are_refused():
    with pytest.raises(ValueError, match="renderer: 'nope'"):
        renderer_scenes("nope")


def test_features_come_from_the_module_that_declares_the_factory(registered):
    assert renderer_features("synthetic") == []
    assert renderer_features(registered) == []  # this module lists none
    pytest.importorskip("embreex")
    from awr_denoise.features import FEATURE_NAMES

    assert renderer_features("tracer") == list(FEATURE_NAMES)


def test_mitsuba_lists_the_features_its_aov_integrator_renders():
    pytest.importorskip("mitsuba")
    from awr_denoise.adapters.mitsuba import FEATURES

    assert renderer_features("mitsuba") == list(FEATURES) == ["albedo", "normal", "depth"]
