"""The OIDN guide (awr_denoise/guides.py): features used, inputs checked, install hint, and its use as a guide."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest
from scipy import ndimage

from awr_denoise import SampleBuffer, SampleRequest, guides, reconstruct, reconstruct_detailed
from awr_denoise.metrics import mse, relmse
from awr_denoise.synthetic import SyntheticRenderer, make_scene

needs_oidn = pytest.mark.skipif(not guides.oidn_available(), reason="the OIDN guide needs the extra oidn (pyoidn)")


def _textured(seed=0, spp=4):
    """A checker texture under noise with its exact albedo and a flat normal as features."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:64, 0:64]
    albedo = np.where((rows // 8 + cols // 8) % 2 == 0, 0.8, 0.2)[..., None] * np.ones(3)
    samples = rng.exponential(np.broadcast_to(albedo, (spp,) + albedo.shape))
    count = np.full((64, 64), spp)
    normal = np.broadcast_to([0.0, 0.0, 1.0], albedo.shape)
    features = {"albedo": SampleBuffer.from_moments(count, albedo, np.zeros_like(albedo)),
                "normal": SampleBuffer.from_moments(count, normal, np.zeros_like(albedo), channels=("X", "Y", "Z"))}
    return albedo, SampleBuffer.from_moments(count, samples.mean(0), samples.var(0, ddof=1), features=features)


@needs_oidn
def test_oidn_uses_the_buffers_albedo_and_normal():
    clean, buf = _textured()
    with_features = guides.oidn(buf)
    bare = SampleBuffer.from_moments(buf.count, buf.mean, buf.variance)
    without = guides.oidn(bare)
    assert with_features.shape == (64, 64, 3) and with_features.dtype == np.float64
    assert mse(with_features, clean) < 0.5 * mse(without, clean)  # the texture's edges come from the albedo
    np.testing.assert_allclose(guides.oidn(bare, albedo=clean, normal=buf.features["normal"].mean), with_features,
                               rtol=1e-6, atol=1e-7)


def _noisy_albedo(seed=0, spp=8, r=3):
    """A checker seen through a lens: each sample sees the texture up to ``r`` pixels away, its radiance that
    albedo times an exponential shading, its albedo feature that albedo (as noisy as the radiance's mean,
    as a renderer's first-hit albedo is). Returns the expected image (the texture's box blur) and the buffer."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:64, 0:64]
    texture = np.where((rows // 8 + cols // 8) % 2 == 0, 0.8, 0.2)[..., None] * np.ones(3)
    seen = np.array([texture[np.clip(rows + rng.integers(-r, r + 1, rows.shape), 0, 63),
                             np.clip(cols + rng.integers(-r, r + 1, cols.shape), 0, 63)] for _ in range(spp)])
    radiance = seen * rng.exponential(size=seen.shape[:-1] + (1,))
    expected = ndimage.uniform_filter(texture, (2 * r + 1, 2 * r + 1, 1), mode="nearest")
    count = np.full((64, 64), spp)
    normal = np.broadcast_to([0.0, 0.0, 1.0], texture.shape)
    features = {"albedo": SampleBuffer.from_moments(count, seen.mean(0), seen.var(0, ddof=1)),
                "normal": SampleBuffer.from_moments(count, normal, np.zeros_like(texture), channels=("X", "Y", "Z"))}
    return expected, SampleBuffer.from_moments(count, radiance.mean(0), radiance.var(0, ddof=1), features=features)


@needs_oidn
def test_noisy_features_are_denoised_before_oidn_uses_them():
    """By default (``auxiliary="prefilter"``) OIDN's own filters denoise the albedo and normal first and the colour
    is denoised with them as clean, OIDN's way with noisy auxiliary images. Here (seed 0, 8 spp) OIDN's MSE is
    0.61x that with them given as noisy (``"noisy"``, what the guide did before) and the guided reconstruction's
    0.84x; taken as clean unfiltered (``"clean"``) it is 5.7x."""
    expected, buf = _noisy_albedo()
    error = {aux: mse(guides.oidn(buf, auxiliary=aux), expected) for aux in ("prefilter", "noisy", "clean")}
    np.testing.assert_array_equal(guides.oidn(buf), guides.oidn(buf, auxiliary="prefilter"))
    assert error["prefilter"] < 0.75 * error["noisy"] < 0.75 * error["clean"], error
    guided = {aux: mse(reconstruct(buf, guide=guides.oidn(buf, auxiliary=aux)), expected) for aux in ("prefilter", "noisy")}
    assert guided["prefilter"] < 0.9 * guided["noisy"], guided


@needs_oidn
def test_how_the_auxiliary_images_reach_oidn(monkeypatch):
    """"prefilter" denoises the albedo and normal with OIDN's filter for each and hands them to the colour's filter
    as clean (cleanAux), "clean" the given ones as clean, "noisy" the given ones as noisy, "none" neither; without
    an albedo nothing is prefiltered or called clean."""
    calls = []
    real = guides._filtered

    def recorded(pyoidn, inputs, images, quality, flags, clip):
        calls.append((inputs, {k: v.copy() for k, v in images.items()}, dict(flags)))
        return real(pyoidn, inputs, images, quality, flags, clip)

    monkeypatch.setattr(guides, "_filtered", recorded)
    _, buf = _noisy_albedo()
    given = np.asarray(buf.features["albedo"].mean, np.float32)
    out = {}
    for aux in guides.AUXILIARY:
        calls.clear()
        guides.oidn(buf, auxiliary=aux)
        out[aux] = list(calls)
    assert [c[0] for c in out["prefilter"]] == [("albedo",), ("normal",), ("color", "albedo", "normal")]
    (_, pre_in, _), _, (_, pre_images, pre_flags) = out["prefilter"]
    np.testing.assert_array_equal(pre_in["albedo"], given)  # the prefilter's input: the buffer's albedo
    assert not np.array_equal(pre_images["albedo"], given) and 0 <= pre_images["albedo"].min() <= 1
    assert pre_flags == {"hdr": True, "cleanAux": True}
    for aux, clean in (("noisy", False), ("clean", True)):
        ((inputs, images, flags),) = out[aux]
        assert inputs == ("color", "albedo", "normal") and flags == {"hdr": True, "cleanAux": clean}
        np.testing.assert_array_equal(images["albedo"], given)
    ((inputs, _, flags),) = out["none"]
    assert inputs == ("color",) and flags == {"hdr": True, "cleanAux": False}


@needs_oidn
def test_prefiltering_from_threads_gives_the_images_of_one_thread():
    """The prefilters are made once and shared: calls from several threads take them in turn."""
    from concurrent.futures import ThreadPoolExecutor
    buffers = [_noisy_albedo(seed)[1] for seed in range(4)]
    alone = [guides.oidn(b) for b in buffers]
    with ThreadPoolExecutor(4) as pool:
        together = list(pool.map(guides.oidn, buffers))
    for a, b in zip(alone, together):
        np.testing.assert_array_equal(a, b)


@needs_oidn
def test_the_oidn_guide_as_a_function_of_the_buffer():
    """``guide=guides.oidn`` is called on the buffer; the result is recorded as guided."""
    clean, buf = _textured()
    result = reconstruct_detailed(buf, guide=guides.oidn, variance_probes=0)
    np.testing.assert_array_equal(result.image, reconstruct(buf, guide=guides.oidn(buf)))
    assert result.parameters["guide"] is True


@needs_oidn
@pytest.mark.parametrize("name", ["edges", "hdr_source"])
def test_the_oidn_guide_keeps_the_mean_and_never_exceeds_the_plain_means_error(name):
    """On the synthetic scenes (no features; 8 spp, three seeds): MSE and relMSE at or below the
    plain mean's, the image mean exact. Against the default, measured: 0.47x its relMSE (0.49x its
    MSE) on ``edges`` and 0.78x (0.82x) next to the small bright light of ``hdr_source``, where
    OIDN dims the light's rim within what 8 samples can tell: 1.11x (0.88x) there while the
    projection kept the means' scale band, an earlier version."""
    errors = np.zeros((3, 2))
    for seed in range(3):
        scene = make_scene(name, (64, 64))
        buf = SyntheticRenderer(scene, seed=seed)(SampleRequest.uniform(scene.shape, 8))
        ref = scene.reference()
        out = reconstruct(buf, guide=guides.oidn)
        np.testing.assert_allclose(out.mean(axis=(0, 1)), buf.mean.mean(axis=(0, 1)), rtol=1e-9)
        for i, image in enumerate((buf.mean, reconstruct(buf), out)):
            errors[i] += (relmse(image, ref), mse(image, ref))
    assert (errors[2] <= errors[0]).all(), errors


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"albedo": np.zeros((64, 63, 3))}, r"albedo: shape \(64, 63, 3\) does not match the buffer's \(64, 64, 3\)"),
    ({"albedo": np.full((64, 64, 3), np.nan)}, r"albedo: 12288 values are NaN or infinite"),
    ({"quality": "best"}, r"quality: 'best' is not one of high, balanced, fast"),
    ({"auxiliary": "denoised"}, r"auxiliary: 'denoised' is not one of prefilter, noisy, clean, none"),
    ({"auxiliary": None}, r"auxiliary: None is not one of prefilter, noisy, clean, none"),
    ({"albedo": np.zeros((64, 63, 3)), "auxiliary": "none"}, r"albedo: shape \(64, 63, 3\) does not match"),
])
def test_bad_auxiliary_images_are_refused(kwargs, message):
    _, buf = _textured()
    with pytest.raises(ValueError, match=message):
        guides.oidn(buf, **kwargs)


@pytest.mark.parametrize(("kwargs", "message"), [
    # These were cast (the imaginary part dropped with numpy's ComplexWarning, True read as 1, a mask dropped).
    ({"albedo": np.full((64, 64, 3), 0.5 + 1j)}, "albedo: complex values are not supported"),
    ({"albedo": np.ones((64, 64, 3), bool)}, "albedo: expected a numeric array, got dtype bool"),
    ({"albedo": np.full((64, 64, 3), 0.5, object)}, "albedo: expected a numeric array, got dtype object"),
    ({"albedo": np.full((64, 64, 3), 0.5), "normal": np.ma.masked_greater(np.full((64, 64, 3), 2.0), 1)},
     "normal: a masked array with 12288 masked entries"),
])
def test_auxiliary_images_of_other_kinds_are_refused(kwargs, message):
    _, buf = _textured()
    with pytest.raises(TypeError, match=message):
        guides.oidn(buf, **kwargs)


class _FailingOIDN:
    """pyoidn's shape, whose filters fail when run: the device's error, or the bindings' own exception."""

    OIDN_FILTER_TYPE_RT, OIDN_FORMAT_FLOAT3, OIDN_IMAGE_OUTPUT, OIDN_QUALITY_HIGH = "RT", 3, "output", 1

    def __init__(self, raises=False):
        self.raises, self.released = raises, []
        outer = self

        class Device:
            error = None

            def commit(self):
                pass

            def get_error(self):
                return self.error

            def release(self):
                outer.released.append("device")

        class Filter:
            def __init__(self, device, kind):
                self.device = device

            def set_image(self, *args):
                pass

            set_bool = set_quality = set_image

            def commit(self):
                pass

            def execute(self):
                if outer.raises:
                    raise RuntimeError("bad alloc")
                self.device.error = "out of memory"

            def release(self):
                outer.released.append("filter")

        self.Device, self.Filter = Device, Filter


@pytest.mark.parametrize(("raises", "words"), [(False, "out of memory"), (True, "bad alloc")])
def test_an_oidn_failure_is_a_backend_error_that_names_oidn(monkeypatch, raises, words):
    """OIDN failing (its device's error or the bindings' exception) raises BackendError, a RuntimeError, naming
    the filter and keeping OIDN's words; the failed filter is released and made anew next time."""
    from awr_denoise.errors import BackendError
    fake = _FailingOIDN(raises)
    monkeypatch.setitem(sys.modules, "pyoidn", fake)
    monkeypatch.setattr(guides, "_oidn", {})
    _, buf = _textured()
    with pytest.raises(BackendError, match=f"^OIDN albedo failed: {words}$") as caught:
        guides.oidn(buf)
    assert isinstance(caught.value, RuntimeError) and fake.released == ["filter"]
    assert set(guides._oidn) == {"device"}
    with pytest.raises(BackendError, match=f"^OIDN color failed: {words}$"):
        guides.oidn(buf, auxiliary="none")


def test_an_oidn_library_that_does_not_load_is_said_to_be_unavailable(monkeypatch):
    """pyoidn loads OIDN's library when first used: an OSError there (a missing or broken library) is
    BackendUnavailableError naming OIDN and what to reinstall, not an OSError about a file."""
    from awr_denoise.errors import BackendUnavailableError
    fake = _FailingOIDN()

    def unloadable():
        raise OSError("libOpenImageDenoise.so.2: cannot open shared object file")

    fake.Device = unloadable
    monkeypatch.setitem(sys.modules, "pyoidn", fake)
    monkeypatch.setattr(guides, "_oidn", {})
    _, buf = _textured()
    with pytest.raises(BackendUnavailableError, match=r"^OIDN cannot start: its library did not load \(libOpen"
                                                      r".*\); reinstall the extra: pip install --force-reinstall"):
        guides.oidn(buf)
    assert guides._oidn == {}


def test_the_oidn_guide_with_its_settings(monkeypatch):
    """``OIDNGuide`` calls ``oidn`` with its settings, checked when it is made, pickles, and the reconstruction
    records them (beside an alpha too, where the colour is reconstructed apart)."""
    import pickle
    seen, oidn = [], guides.oidn
    monkeypatch.setattr(guides, "oidn", lambda buffer, **kw: seen.append(kw) or np.asarray(buffer.mean[..., :3]))
    guide = guides.OIDNGuide(auxiliary="none", quality="fast")
    assert pickle.loads(pickle.dumps(guide)) == guide
    _, rgb = _textured()
    rgba = SampleBuffer.from_moments(rgb.count, np.concatenate([rgb.mean, rgb.mean[..., :1]], 2),
                                     np.concatenate([rgb.variance, rgb.variance[..., :1]], 2),
                                     channels=["R", "G", "B", "A"])
    for buffer in (rgb, rgba):
        result = reconstruct_detailed(buffer, guide=guide, variance_probes=0)
        assert (result.parameters["guide_auxiliary"], result.parameters["guide_quality"]) == ("none", "fast")
        assert result.parameters["guide"] is True
    assert seen == [{"quality": "fast", "auxiliary": "none"}] * 2
    # The way OIDN took the features: as asked with an albedo, none without one; guides.oidn records its defaults.
    noisy = guides.OIDNGuide(auxiliary="noisy")
    assert noisy.recorded(rgb)["guide_auxiliary"] == "noisy" and noisy.recorded(rgba)["guide_auxiliary"] == "none"
    albedo_alone = SampleBuffer.from_moments(rgb.count, rgb.mean, rgb.variance,
                                             features={"albedo": rgb.features["albedo"]})
    clean = guides.OIDNGuide(auxiliary="clean")  # OIDN takes the features as clean only as a pair
    assert clean.recorded(rgb)["guide_auxiliary"] == "clean"
    assert clean.recorded(albedo_alone)["guide_auxiliary"] == "noisy"
    assert oidn.recorded(rgb) == {"guide_auxiliary": "prefilter", "guide_quality": "high"}
    assert reconstruct_detailed(rgba, guide=noisy, variance_probes=0).parameters["guide_auxiliary"] == "none"
    assert guides.GUIDES["oidn"] == guides.OIDNGuide()
    for kwargs, message in (({"auxiliary": "dirty"}, "auxiliary: 'dirty' is not one of"),
                            ({"quality": "best"}, "quality: 'best' is not one of high, balanced, fast"),
                            ({"quality": None}, "quality: None")):
        with pytest.raises(ValueError, match=message):
            guides.OIDNGuide(**kwargs)


@needs_oidn
def test_beside_an_alpha_the_oidn_guide_is_the_colours():
    """``guides.oidn`` refused an R,G,B,A buffer (OIDN denoises R,G,B only), so no buffer with an
    alpha could be guided. It now denoises the colour, in R,G,B order whatever the buffer's (a
    B,G,R buffer went to OIDN as B,G,R), and the guide of the colour guides the colour alone: the
    colour is the R,G,B buffer's guided result to the bit, the alpha its unguided one."""
    _, rgb = _textured()
    alpha = np.clip(rgb.mean[..., :1], 0, 1)
    rgba = SampleBuffer.from_moments(rgb.count, np.concatenate([rgb.mean, alpha], 2),
                                     np.concatenate([rgb.variance, np.full_like(alpha, 0.01)], 2),
                                     channels=["R", "G", "B", "A"], features=rgb.features)
    abgr = rgba.select((3, 2, 1, 0))
    guide = guides.oidn(rgb)
    np.testing.assert_array_equal(guides.oidn(rgba), guide)
    np.testing.assert_array_equal(guides.oidn(abgr), guide[..., ::-1])
    np.testing.assert_array_equal(guides.oidn(abgr.select((1, 2, 3))), guide[..., ::-1])
    for buffer, colour, alpha_at in ((rgba, (0, 1, 2), 3), (abgr, (1, 2, 3), 0)):
        out = reconstruct(buffer, guide=guides.oidn, guide_projection=0.25)
        alone = buffer.select(colour)
        np.testing.assert_array_equal(out[..., list(colour)], reconstruct(alone, guide=guides.oidn(alone),
                                                                          guide_projection=0.25))
        np.testing.assert_array_equal(out[..., alpha_at], reconstruct(buffer.select((alpha_at,)))[..., 0])
        np.testing.assert_array_equal(reconstruct(buffer, guide=guides.oidn(buffer), guide_projection=0.25), out)
    np.testing.assert_array_equal(reconstruct(rgba, guide=guide)[..., :3], reconstruct(rgb, guide=guide))


def test_a_guide_of_the_colour_alone_needs_one_colour():
    """Only a buffer with one colour beside other channels takes a guide of the colour alone."""
    mean = np.ones((8, 8, 4))
    rgba = SampleBuffer.from_moments(np.full((8, 8), 2), mean, mean, channels=["R", "G", "B", "A"])
    assert reconstruct(rgba, guide=np.ones((8, 8, 3))).shape == (8, 8, 4)
    with pytest.raises(ValueError, match=r"guide: shape \(8, 8, 2\) does not match the buffer's \(8, 8, 4\) nor its "
                                         r"colour's \(8, 8, 3\)"):
        reconstruct(rgba, guide=np.ones((8, 8, 2)))
    plain = SampleBuffer.from_moments(np.full((8, 8), 2), mean, mean, channels=["c0", "c1", "c2", "c3"])
    with pytest.raises(ValueError, match=r"guide: shape \(8, 8, 3\) does not match the buffer's \(8, 8, 4\)$"):
        reconstruct(plain, guide=np.ones((8, 8, 3)))


def test_oidn_needs_rgb_and_an_albedo_with_a_normal():
    one = SampleBuffer.from_moments(np.full((8, 8), 2), np.ones((8, 8, 1)), np.ones((8, 8, 1)))
    two_layers = SampleBuffer.from_moments(np.full((8, 8), 2), np.ones((8, 8, 6)), np.ones((8, 8, 6)),
                                           channels=["a.R", "a.G", "a.B", "b.R", "b.G", "b.B"])
    for buffer in (one, two_layers):
        with pytest.raises(ValueError, match=r"buffer: OIDN \(guides.oidn / --guide oidn\) denoises one three-channel "
                                             r"colour \(R,G,B\); this buffer's channels are (Y|a.R,.*,b.B)$"):
            guides.oidn(buffer)
    rgb = SampleBuffer.from_moments(np.full((8, 8), 2), np.ones((8, 8, 3)), np.ones((8, 8, 3)))
    with pytest.raises(ValueError, match=r"normal: OIDN takes a normal image only with an albedo image"):
        guides.oidn(rgb, normal=np.zeros((8, 8, 3)))


def test_without_pyoidn_the_error_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyoidn", None)  # import pyoidn now raises ImportError
    _, buf = _textured()
    assert not guides.oidn_available()
    with pytest.raises(ImportError, match=r'needs pyoidn .*pip install "awr-denoise\[oidn\]"'):
        guides.oidn(buf)


def test_oidn_names_an_image_given_for_the_buffer():
    """`guides.oidn(image)` raised AttributeError "'numpy.ndarray' object has no attribute 'channels'"."""
    for given in (np.ones((4, 4, 3)), None):
        with pytest.raises(TypeError, match="^buffer: expected a SampleBuffer, got "):
            guides.oidn(given)


@needs_oidn
@pytest.mark.parametrize("power", [330, -300])
def test_oidn_denoises_means_beyond_float32_at_their_scale(power):
    """Means of 1e100 were clipped to float32's largest value before OIDN, and the guide came back far
    off the colour (a red-team pass); 1e-60 flushed to zero. In by a power of two and back out, the
    same image as at the usual scale, bit for bit."""
    rng = np.random.default_rng(0)
    mean, count = 0.5 + 0.1 * rng.random((32, 32, 3)), np.full((32, 32), 8)
    base = guides.oidn(SampleBuffer.from_moments(count, mean, np.full((32, 32, 3), 0.01)))
    scaled = guides.oidn(SampleBuffer.from_moments(count, np.ldexp(mean, power), np.zeros((32, 32, 3))))
    np.testing.assert_array_equal(np.ldexp(base, power), scaled)


@needs_oidn
def test_oidn_denoises_subnormal_means():
    """Means below float64's least normal number (1e-309) raised OverflowError: the factor 2**1030
    that would bring them in passes float64 (a review). The array is scaled by its exponent."""
    rng = np.random.default_rng(0)
    mean, count = 0.5 + 0.1 * rng.random((32, 32, 3)), np.full((32, 32), 8)
    base = guides.oidn(SampleBuffer.from_moments(count, mean, np.zeros((32, 32, 3))))
    tiny = guides.oidn(SampleBuffer.from_moments(count, np.ldexp(mean, -1030), np.zeros((32, 32, 3))))
    np.testing.assert_allclose(np.ldexp(tiny, 1030), base, rtol=1e-5)


_FORKED_OIDN = """
import multiprocessing, sys
import numpy as np
from awr_denoise import SampleBuffer, guides
rng = np.random.default_rng(0)
count = np.full((32, 32), 8)
albedo = SampleBuffer.from_moments(count, rng.uniform(0.2, 0.8, (32, 32, 3)), np.full((32, 32, 3), 0.01))
buf = SampleBuffer.from_moments(count, rng.uniform(0, 1, (32, 32, 3)), np.full((32, 32, 3), 0.1),
                                features={"albedo": albedo})
expected = guides.oidn(buf)  # the parent's device and filters exist now
context = multiprocessing.get_context("fork")
queue = context.Queue()
child = context.Process(target=lambda: queue.put(guides.oidn(buf)), daemon=True)  # ended with the script
child.start()
image = queue.get(timeout=120)
child.join(10)
sys.exit(0 if np.array_equal(image, expected) else 3)
"""


@needs_oidn
@pytest.mark.skipif(not hasattr(os, "register_at_fork"), reason="fork is POSIX's")
def test_a_forked_child_of_a_process_that_ran_oidn_runs_it_too():
    """OIDN's device, made once per process, hung for ever in a child forked after the parent had used it (a
    user's process pool with the fork start method, the default on Linux before Python 3.14): the child makes
    its own, with the same image. In a process of its own: forked from the test run, the child could also
    inherit a lock that one of the run's other threads held at the fork, and hang for that reason."""
    import subprocess

    run = subprocess.run([sys.executable, "-c", _FORKED_OIDN], capture_output=True, text=True, timeout=180)
    assert run.returncode == 0, run.stderr[-2000:]
