"""The Mitsuba 3 adapter: exact requests, agreement with Mitsuba's film, addressed randomness."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

from awr_denoise import AdaptiveSampler, Renderer, SampleBuffer, SampleRequest
from awr_denoise.adapters import mitsuba_scenes
from awr_denoise.adapters.mitsuba import FEATURES, MitsubaRenderer, create_renderer
from awr_denoise.errors import InputFileError

SHAPE = (32, 32)


@pytest.fixture(scope="module")
def cornell(mi) -> MitsubaRenderer:
    return create_renderer("cornell_box", shape=SHAPE, seed=11)


def _random_request(shape, rng, *, high=5, round=0) -> SampleRequest:
    counts = rng.integers(0, high, shape)
    first = rng.integers(0, 50, shape)
    return SampleRequest(counts, first, round)


# ---------------------------------------------------------------------------- no Mitsuba needed
def test_scene_names_are_listed():
    assert mitsuba_scenes.SCENE_NAMES == ("cornell_box", "envmap_sun", "glossy_glass", "dof_checker")
    assert mitsuba_scenes.ALL_SCENES == mitsuba_scenes.SCENE_NAMES + ("indirect_room", "fog_spot", "shaded_lamp")
    with pytest.raises(ValueError, match="bundled Mitsuba scene"):
        mitsuba_scenes.scene_dict("no_such_scene")


# ---------------------------------------------------------------------------- the protocol
def test_satisfies_the_renderer_protocols(cornell):
    assert isinstance(cornell, Renderer)
    assert cornell.channels == ("R", "G", "B")
    assert cornell.shape == SHAPE
    assert {"samples", "nonfinite", "seconds"} <= set(cornell.stats)
    for method in ("trace_samples", "close", "render_features"):
        assert callable(getattr(cornell, method))
    import awr_denoise.requests as requests

    assert isinstance(cornell, requests.SampleTracer)
    assert isinstance(cornell, requests.FeatureTracer)
    assert cornell.features == ()


def test_exact_counts_per_pixel(cornell, rng):
    request = _random_request(SHAPE, rng)
    before = cornell.stats["samples"]
    buffer = cornell(request)
    np.testing.assert_array_equal(buffer.count, request.counts)
    assert buffer.channels == ("R", "G", "B")
    assert buffer.nonfinite == 0
    assert cornell.stats["samples"] - before == request.total
    assert np.isfinite(buffer.mean).all() and (buffer.mean >= 0).all()
    rows, cols, index = request.pixel_list()
    values = cornell.trace_samples(rows, cols, index)
    assert values.shape == (request.total, 3) and values.dtype == np.float64
    # The request path lists its samples on the device; they are the samples trace_samples gives.
    expected = SampleBuffer.from_samples(rows * SHAPE[1] + cols, values, SHAPE)
    np.testing.assert_allclose(buffer.mean, expected.mean, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(buffer.variance, expected.variance, rtol=1e-9, atol=1e-15)


def test_empty_request(cornell):
    buffer = cornell(SampleRequest.uniform(SHAPE, 0))
    assert buffer.total_samples == 0 and buffer.shape == SHAPE


def test_agrees_with_mitsubas_own_film_render(mi, cornell):
    """z-scores of 2x2 block means against Mitsuba's film render with a box filter (independent seeds)."""
    spp, renders = 256, 16
    buffer = cornell(SampleRequest.uniform(SHAPE, spp))
    films = np.stack([np.array(mi.render(cornell.scene, spp=spp // renders, seed=1000 + k), dtype=np.float64)
                      for k in range(renders)])

    def blocks(a):
        return a.reshape(SHAPE[0] // 2, 2, SHAPE[1] // 2, 2, -1).mean(axis=(1, 3))

    ours, ours_var = blocks(buffer.mean), blocks(buffer.variance_of_mean()) / 4
    film_blocks = np.stack([blocks(f) for f in films])
    theirs, theirs_var = film_blocks.mean(0), film_blocks.var(0, ddof=1) / renders
    spread = ours_var + theirs_var
    lit = spread > 0
    z = (ours - theirs)[lit] / np.sqrt(spread[lit])
    assert lit.sum() > 500
    assert abs(z.mean()) < 0.15, z.mean()
    assert 0.85 < z.std() < 1.25, z.std()
    # The image means agree to within their standard errors (both around 2e-3 relative here).
    total_se = math.sqrt(ours_var.sum() + theirs_var.sum()) / ours.size
    assert abs(ours.mean() - theirs.mean()) < 4 * total_se


@pytest.mark.parametrize("integrator", ["volpath", "direct", "prb"])
def test_other_integrators_agree_with_mitsuba(mi, integrator):
    """C++ integrators and Mitsuba's Python differentiable ones (prb) give Mitsuba's image mean."""
    d = mitsuba_scenes.scene_dict("cornell_box", (16, 16))
    d["integrator"] = {"type": integrator} if integrator == "direct" else {"type": integrator, "max_depth": 4}
    renderer = create_renderer(d, seed=5)
    buffer = renderer(SampleRequest.uniform((16, 16), 128))
    films = np.stack([np.array(mi.render(renderer.scene, spp=16, seed=50 + k), dtype=np.float64) for k in range(8)])
    ours_se = math.sqrt(buffer.variance_of_mean().sum()) / buffer.mean.size
    theirs_se = films.mean(axis=(1, 2, 3)).std(ddof=1) / math.sqrt(len(films))
    assert abs(buffer.mean.mean() - films.mean()) < 4 * math.hypot(ours_se, theirs_se)


# ---------------------------------------------------------------------------- reproducibility
def test_same_seed_and_request_give_identical_buffers(cornell, rng):
    request = _random_request(SHAPE, rng)
    a = cornell(request)
    b = create_renderer("cornell_box", shape=SHAPE, seed=11)(request)
    np.testing.assert_array_equal(a.mean, b.mean)
    np.testing.assert_array_equal(a.variance, b.variance)


def test_samples_are_addressed_by_pixel_and_index(cornell, rng):
    rows, cols, index = rng.integers(0, 32, 400), rng.integers(0, 32, 400), rng.integers(0, 10_000, 400)
    values = cornell.trace_samples(rows, cols, index)
    order = rng.permutation(400)
    np.testing.assert_array_equal(cornell.trace_samples(rows[order], cols[order], index[order]), values[order])
    np.testing.assert_array_equal(cornell.trace_samples(rows[:5], cols[:5], index[:5]), values[:5])


def test_rounds_split_like_one_request(cornell):
    whole = cornell(SampleRequest.uniform(SHAPE, 8))
    first = cornell(SampleRequest.uniform(SHAPE, 3, round=0))
    rest = cornell(SampleRequest.uniform(SHAPE, 5, first_index=3, round=1))
    merged = first.merge(rest)
    np.testing.assert_allclose(merged.mean, whole.mean, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(merged.variance, whole.variance, rtol=1e-9, atol=1e-15)
    # Later rounds draw new samples: not a copy of the first round's.
    assert not np.array_equal(rest.mean, cornell(SampleRequest.uniform(SHAPE, 5, round=1)).mean)


def test_different_seeds_give_different_samples(cornell):
    other = create_renderer("cornell_box", shape=SHAPE, seed=12)
    request = SampleRequest.uniform(SHAPE, 2)
    lit = cornell(request).mean.sum(axis=2) > 0
    assert (cornell(request).mean != other(request).mean)[lit].all()


def test_large_requests_are_split_exactly(mi):
    small = create_renderer("cornell_box", shape=SHAPE, seed=11, batch_size=1000)
    request = SampleRequest.uniform(SHAPE, 2)
    whole = create_renderer("cornell_box", shape=SHAPE, seed=11)(request)
    split = small(request)
    assert small.stats["launches"] == math.ceil(request.total / 1000)
    np.testing.assert_array_equal(split.count, whole.count)
    np.testing.assert_allclose(split.mean, whole.mean, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(split.variance, whole.variance, rtol=1e-9, atol=1e-15)


def test_every_call_reuses_one_kernel(cornell, rng):
    """Requests of any size and content run the same compiled kernel (no compile per call)."""
    import drjit as dr

    def largest_kernel(call):
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        try:
            dr.kernel_history()  # clears the history
            call()
            history = dr.kernel_history()
        finally:
            dr.set_flag(dr.JitFlag.KernelHistory, False)
        return max(history, key=lambda k: k.get("operation_count", 0))["hash"]

    listed = {largest_kernel(lambda: cornell.trace_samples(rng.integers(0, 32, n), rng.integers(0, 32, n),
                                                           rng.integers(0, 99, n)))
              for n in (1000, 1001, 2048, 333)}
    requested = {largest_kernel(lambda: cornell(_random_request(SHAPE, rng, high=high))) for high in (2, 5, 9)}
    assert len(listed) == 1 and len(requested) == 1


# ---------------------------------------------------------------------------- the loop
def test_runs_in_the_adaptive_sampler(cornell):
    sampler = AdaptiveSampler(SHAPE, seed=3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        buffer = sampler.run(cornell, total_spp=8)
    assert buffer.total_samples == 8 * SHAPE[0] * SHAPE[1]
    assert sampler.round > 2
    assert buffer.count.max() > buffer.count.min()  # samples went where the wavelets asked


# ---------------------------------------------------------------------------- features
def test_features_on_the_same_rays(cornell, rng):
    request = _random_request(SHAPE, rng, high=4)
    features = cornell.render_features(request)
    assert set(features) == set(FEATURES)
    for name, buffer in features.items():
        assert buffer.channels == FEATURES[name][1]
        np.testing.assert_array_equal(buffer.count, request.counts)
    values = cornell.trace_feature_values(*request.pixel_list())
    hit = values["depth"][:, 0] > 0
    assert hit.mean() > 0.5
    np.testing.assert_allclose(np.linalg.norm(values["normal"][hit], axis=1), 1.0, atol=1e-4)
    assert (values["albedo"] >= 0).all() and (values["albedo"] <= 1).all()
    # The camera sits 3.9 in front of the back wall at z = -1; nothing is farther than ~6.
    assert values["depth"].max() < 6.5
    only = cornell.render_features(request, ["depth"])
    assert list(only) == ["depth"]
    np.testing.assert_array_equal(only["depth"].mean, features["depth"].mean)
    with pytest.raises(ValueError, match="features are"):
        cornell.render_features(request, ["roughness"])


def test_requests_carry_features_on_the_same_rays(cornell, rng):
    request = _random_request(SHAPE, rng, high=4)
    plain = cornell(request)
    with_features = create_renderer("cornell_box", shape=SHAPE, seed=11, features="all")
    buffer = with_features(request)
    # The radiance does not change when features are asked for: the same samples, the same rays.
    np.testing.assert_array_equal(buffer.mean, plain.mean)
    np.testing.assert_array_equal(buffer.variance, plain.variance)
    assert tuple(buffer.features) == ("albedo", "normal", "depth")
    separate = cornell.render_features(request)
    for name, feature in buffer.features.items():
        np.testing.assert_array_equal(feature.count, request.counts)
        np.testing.assert_allclose(feature.mean, separate[name].mean, rtol=1e-12, atol=1e-12)
    rows, cols, index = request.pixel_list()
    radiance, per_sample = with_features.trace_features(rows, cols, index)
    np.testing.assert_array_equal(radiance, cornell.trace_samples(rows, cols, index))
    assert set(per_sample) == {"albedo", "normal", "depth"}
    assert cornell.trace_features(rows, cols, index)[1] == {}


def test_depth_is_measured_along_the_view_axis(cornell):
    # The back wall faces the camera: its depth along the view axis is one number at every pixel,
    # while the distance along the ray grows towards the image's edges.
    request = SampleRequest.uniform(SHAPE, 4)
    values = cornell.trace_feature_values(*request.pixel_list(), names=("normal", "depth"))
    wall = (values["normal"][:, 2] > 0.999) & (values["depth"][:, 0] > 0)
    deepest = values["depth"][wall, 0].max()
    back = wall & (values["depth"][:, 0] > deepest - 0.05)
    assert back.sum() > 100
    assert np.ptp(values["depth"][back, 0]) < 1e-4 * deepest


# ---------------------------------------------------------------------------- scenes and sources
@pytest.mark.parametrize("name", mitsuba_scenes.ALL_SCENES)
def test_bundled_scenes_render(mi, name):
    renderer = create_renderer(name, shape=(12, 16), seed=1)
    assert renderer.shape == (12, 16)
    buffer = renderer(SampleRequest.uniform((12, 16), 2))
    # the scenes lit through rare paths are mostly 0 at 2 spp (test_heavy_tailed_scenes_are_lit_through_rare_paths)
    least = 0.01 if name in mitsuba_scenes.SCENE_NAMES else 0.0
    assert buffer.total_samples == 12 * 16 * 2 and buffer.mean.mean() > least
    assert renderer.stats["nonfinite"] == 0


@pytest.mark.parametrize("name", mitsuba_scenes.HEAVY_TAILED_SCENES)
def test_heavy_tailed_scenes_are_lit_through_rare_paths(mi, name):
    """mitsuba_scenes: most samples of these scenes are exactly 0, so that most pixels' first samples all are."""
    shape = (24, 32)
    buffer = create_renderer(name, shape=shape, seed=1)(SampleRequest.uniform(shape, 4))
    assert (buffer.mean.max(axis=-1) == 0).mean() > 0.7
    # and yet the room is lit: 256 samples a pixel leave black only the void seen past its open side
    image = np.array(mi.render(mi.load_dict(mitsuba_scenes.scene_dict(name, shape)), spp=256, seed=2))
    assert (image.max(axis=-1) > 0).mean() > 0.9


def test_envmap_sun_is_lit_mostly_by_its_small_sun(mi):
    """docs/integrate_mitsuba.md: the sun is 31 texels and 60% of the horizontal irradiance."""
    sky = np.array(mitsuba_scenes.scene_dict("envmap_sun", (8, 8))["sky"]["bitmap"], dtype=np.float64)
    h, w, _ = sky.shape
    theta = (np.arange(h) + 0.5) / h * np.pi
    weight = (np.cos(theta) * np.sin(theta) * (np.pi / h) * (2 * np.pi / w))[:, None]  # cos * solid angle
    luminance = sky @ np.array([0.2126, 0.7152, 0.0722])
    upper = np.cos(theta) > 0
    sun = luminance > 100
    share = (luminance * weight * sun)[upper].sum() / (luminance * weight)[upper].sum()
    assert sun.sum() == 31 and 0.58 < share < 0.62


def test_xml_written_by_mitsuba_renders_the_same_samples(mi, tmp_path):
    # The sky's bitmap goes to an EXR file beside the XML, found from there (not from the cwd).
    path = mitsuba_scenes.write_scene_xml("envmap_sun", tmp_path / "env.xml", (20, 30))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["env.xml", "env_sky.exr"]
    from_file = create_renderer(path, seed=4)
    resized = create_renderer(path, shape=(10, 12), seed=4)
    from_name = create_renderer("envmap_sun", shape=(20, 30), seed=4)
    request = SampleRequest.uniform((20, 30), 2)
    assert from_file.shape == (20, 30) and resized.shape == (10, 12)
    # The same samples; the file's transforms are decimal text, so geometry moves by float32 rounding.
    np.testing.assert_allclose(from_file(request).mean, from_name(request).mean, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("name", mitsuba_scenes.ALL_SCENES)
def test_every_bundled_scene_written_as_xml_renders_its_samples(mi, tmp_path, name):
    """write_scene_xml writes each plugin a bundled scene uses (the lamp's cylinder, disk and point light too)."""
    shape = (8, 12)
    request = SampleRequest.uniform(shape, 2)
    from_file = create_renderer(mitsuba_scenes.write_scene_xml(name, tmp_path / f"{name}.xml", shape), seed=3)
    np.testing.assert_allclose(from_file(request).mean, create_renderer(name, shape=shape, seed=3)(request).mean,
                               rtol=1e-4, atol=1e-5)


def test_loaded_scene_and_dict(mi):
    d = mitsuba_scenes.scene_dict("cornell_box", (8, 8))
    scene = mi.load_dict(d)
    request = SampleRequest.uniform((8, 8), 2)
    np.testing.assert_array_equal(create_renderer(scene, seed=2)(request).mean,
                                  create_renderer(d, seed=2)(request).mean)
    with pytest.raises(ValueError, match="cannot be resized"):
        create_renderer(scene, shape=(16, 16))


def test_gaussian_film_filter_warns_once(mi):
    """Once, naming the filter as a scene names it, at the caller's line (it pointed at the adapter's own); and
    not before a scene that is refused (the refusal alone says what is wrong)."""
    d = mi.cornell_box()  # Mitsuba's own Cornell box films through a gaussian filter
    with pytest.warns(UserWarning, match="the film's gaussian filter is not used") as record:
        renderer = create_renderer(d, shape=(8, 8))
        renderer(SampleRequest.uniform((8, 8), 1))
    assert len(record) == 1
    assert "\n" not in str(record[0].message)
    assert record[0].filename == __file__
    d["integrator"] = {"type": "aov", "aovs": "dd.y:depth"}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning would be raised in the refusal's place
        with pytest.raises(ValueError, match="writes AOVs or moments"):
            create_renderer(d, shape=(8, 8))


def test_nonfinite_samples_are_zeroed_and_counted(mi):
    T = mi.ScalarTransform4f
    d = {"type": "scene", "integrator": {"type": "path", "max_depth": 1},
         "sensor": {"type": "perspective", "fov": 60, "to_world": T().look_at(origin=[0, 0, 3], target=[0, 0, 0], up=[0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": 8, "height": 8, "rfilter": {"type": "box"}}},
         "ball": {"type": "sphere", "radius": 0.6, "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1.0}}},
         "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [math.inf, 1.0, 1.0]}}}
    renderer = create_renderer(d)
    buffer = renderer(SampleRequest.uniform((8, 8), 4))
    values = renderer.trace_samples(*SampleRequest.uniform((8, 8), 4).pixel_list())
    sky = (values == 0).all(axis=1)
    assert 0 < buffer.nonfinite < buffer.total_samples
    assert buffer.nonfinite == sky.sum()
    assert renderer.stats["nonfinite"] == 2 * buffer.nonfinite
    np.testing.assert_array_equal(buffer.count, 4)  # zeroed, not dropped: the tracer's policy


def test_registry_names_the_factory():
    from awr_denoise.adapters.mitsuba import create_renderer as factory
    from awr_denoise.renderers import renderer_factory

    assert renderer_factory("mitsuba") is factory


# ---------------------------------------------------------------------------- bad input
def test_bad_input(cornell, mi):
    with pytest.raises(ValueError, match="does not match"):
        cornell(SampleRequest.uniform((8, 8), 1))
    with pytest.raises(TypeError, match="SampleRequest"):
        cornell(np.ones(SHAPE))
    with pytest.raises(ValueError, match="outside"):
        cornell.trace_samples([40], [0], [0])
    with pytest.raises(FileNotFoundError, match="no_such.xml"):
        create_renderer("no_such.xml")
    with pytest.raises(ValueError, match="JIT RGB variant"):
        create_renderer("cornell_box", variant="scalar_rgb")
    with pytest.raises(ValueError, match="seed"):
        create_renderer("cornell_box", seed=-1)
    with pytest.raises(ValueError, match="not a sampling integrator"):
        d = mitsuba_scenes.scene_dict("cornell_box", (8, 8))
        create_renderer({**d, "integrator": {"type": "ptracer"}})


_SCENE = ('<scene version="3.0.0">{integrator}<sensor type="perspective"><film type="hdrfilm">'
          '<integer name="width" value="{w}"/><integer name="height" value="8"/><rfilter type="box"/></film>'
          '</sensor>{more}</scene>')


_PATH = '<integrator type="path"/>'


@pytest.mark.parametrize("case, needle", [
    ("plugin", 'Plugin "nonesuch" not found'),
    ("loop", "include recursion depth"),
    ("parameter", "tx"),
])
def test_a_scene_mitsuba_cannot_load_is_bad_input_naming_the_file(mi, tmp_path, case, needle):
    """Mitsuba's parser errors are the user's scene at fault: an InputFileError naming the file, one
    line (an include loop nests a line per file), not an internal error."""
    more = {"plugin": '<shape type="nonesuch"/>', "loop": '<include filename="loop.xml"/>',
            "parameter": '<shape type="obj"><string name="filename" value="$tx"/></shape>'}[case]
    (tmp_path / "loop.xml").write_text('<scene version="3.0.0"><include filename="loop.xml"/></scene>')
    path = tmp_path / "bad.xml"
    path.write_text(_SCENE.format(w=8, more=more, integrator=_PATH))
    with pytest.raises(InputFileError, match=needle) as info:
        create_renderer(str(path))
    message = str(info.value)
    assert message.startswith(f"{path}: Mitsuba cannot load") and "\n" not in message and len(message) < 500


def test_a_film_without_pixels_a_garbage_mesh_and_a_nan_radius_are_refused_naming_the_scene(mi, tmp_path):
    """A film of width 0 was refused as ``counts: empty image``; a PLY of two bytes that are not text as
    a bare ``'utf-8' codec can't decode``; a radius of NaN rendered without the sphere, exit 0 (a red-team
    pass): each names the scene file."""
    (tmp_path / "w0.xml").write_text(_SCENE.format(w=0, more="", integrator=_PATH).replace(
        '<sensor type="perspective">', '<sensor type="perspective"><float name="fov" value="45"/>'))
    with pytest.raises(ValueError, match=r"w0\.xml: its film \(crop\) is 0x8 pixels; a film needs at least 1x1"):
        create_renderer(str(tmp_path / "w0.xml"))
    (tmp_path / "bad.ply").write_bytes(b"\xa9\xdf")
    mesh = '<shape type="ply"><string name="filename" value="bad.ply"/></shape>'
    (tmp_path / "ply.xml").write_text(_SCENE.format(w=8, more=mesh, integrator=_PATH))
    with pytest.raises(InputFileError, match=r"ply\.xml: Mitsuba cannot load this scene: a file it reads is not"):
        create_renderer(str(tmp_path / "ply.xml"))
    for value, owner, parameter in (("nan", "Sphere", "to_world"), ("1e39", "Sphere", "to_world")):
        sphere = f'<shape type="sphere"><float name="radius" value="{value}"/></shape>'
        (tmp_path / "nan.xml").write_text(_SCENE.format(w=8, more=sphere, integrator=_PATH))
        with pytest.raises(InputFileError, match=rf"nan\.xml: {owner} parameter '{parameter}' holds NaN or Inf"):
            create_renderer(str(tmp_path / "nan.xml"))
    lens = ('<float name="fov" value="45"/><float name="aperture_radius" value="nan"/>'
            '<float name="focus_distance" value="3"/>')
    (tmp_path / "lens.xml").write_text(_SCENE.format(w=8, more="", integrator=_PATH).replace(
        '<sensor type="perspective">', f'<sensor type="thinlens">{lens}'))
    with pytest.raises(InputFileError, match=r"lens\.xml: ThinLensCamera parameter 'aperture_radius' holds NaN"):
        create_renderer(str(tmp_path / "lens.xml"))


def test_a_scene_without_an_integrator_is_refused_naming_it(mi, tmp_path):
    (tmp_path / "bare.xml").write_text(_SCENE.format(w=8, more="", integrator=""))
    with pytest.raises(ValueError, match="bare.xml: the scene declares no integrator"):
        create_renderer(str(tmp_path / "bare.xml"))


def test_cli_refuses_a_film_larger_than_the_size_limits_before_rendering(mi, tmp_path, capsys):
    from awr_denoise.cli.main import main

    (tmp_path / "huge.xml").write_text(_SCENE.format(w=2**21, more="", integrator=_PATH))
    assert main(["render", "--renderer", "mitsuba", str(tmp_path / "huge.xml"), "--spp", "1", "-q",
                 "-o", str(tmp_path / "o.exr")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("awr: error: SCENE") and "film" in err[-1] and "sides up to" in err[-1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["huge.xml"]


def test_missing_libllvm_says_what_to_install():
    script = ("from awr_denoise.adapters.mitsuba import create_renderer\n"
              "try:\n    create_renderer('cornell_box', shape=(4, 4))\n"
              "except RuntimeError as exc:\n    print(exc)\n")
    env = {**os.environ, "DRJIT_LIBLLVM_PATH": os.path.join(os.sep, "nonexistent", "libLLVM.so")}
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        pytest.skip("Mitsuba 3 is not installed")
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "apt-get install libllvm19" in out.stdout and "DRJIT_LIBLLVM_PATH" in out.stdout


def test_missing_libllvm_is_no_internal_error_of_the_command_line(tmp_path):
    """It said "internal error: RuntimeError: ..." (exit 1), as for a bug of ours: it is an extra that cannot
    start, one line saying what to install, exit 1 as for a missing extra, nothing written."""
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        pytest.skip("Mitsuba 3 is not installed")
    env = {**os.environ, "DRJIT_LIBLLVM_PATH": os.path.join(os.sep, "nonexistent", "libLLVM.so")}
    out = subprocess.run([sys.executable, "-m", "awr_denoise.cli.main", "render", "--renderer", "mitsuba", "cornell_box",
                          "--width", "8", "--height", "8", "--spp", "2", "-o", str(tmp_path / "x.exr")],
                         env=env, capture_output=True, text=True, timeout=120)
    lines = [line for line in out.stderr.splitlines() if line.startswith("awr:")]  # Dr.Jit prints its own before
    assert out.returncode == 1 and len(lines) == 1, out.stderr
    assert lines[0].startswith("awr: error: Mitsuba's llvm_ad_rgb variant cannot start") and "internal" not in lines[0]
    assert "apt-get install libllvm19" in lines[0]
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------- the command line
def test_cli_renders_a_bundled_mitsuba_scene_with_features(mi, tmp_path, capsys):
    from awr_denoise.cli.main import main
    from awr_denoise.io import read_sample_buffer

    assert main(["render", "--renderer", "mitsuba", "--list-scenes"]) == 0
    assert capsys.readouterr().out.split() == list(mitsuba_scenes.ALL_SCENES)
    serial, tiled = tmp_path / "serial.exr", tmp_path / "tiled.exr"
    common = ["render", "--renderer", "mitsuba", "cornell_box", "--width", "24", "--height", "16",
              "--spp", "4", "--features", "all", "-q"]
    assert main([*common, "-o", str(serial)]) == 0
    assert main([*common, "-o", str(tiled), "--workers", "2", "--tile", "8"]) == 0
    a, b = read_sample_buffer(serial), read_sample_buffer(tiled)
    assert a.shape == (16, 24) and tuple(a.features) == ("albedo", "normal", "depth")
    # Addressed random numbers: tiles rendered on workers give the serial render's samples.
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_allclose(a.mean, b.mean, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(a.features["depth"].mean, b.features["depth"].mean, rtol=1e-6, atol=1e-7)
    assert main(["render", "--renderer", "synthetic", "edges", "--features", "albedo", "-o",
                 str(tmp_path / "x.exr")]) == 2
    assert "--features" in capsys.readouterr().err
