"""Variance-stabilising domains: invertibility, oddness, delta-method variance, scale equivariance."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from awr_denoise.domains import DOMAIN_NAMES, Domain, resolve_domain

ROUND_TRIP_RTOL = 1e-12
ROUND_TRIP_ATOL = 1e-15
# Central differences with step h = 1e-6 (|x| + k): truncation O(h^2) and rounding ~1e-10 relative.
DERIVATIVE_RTOL = 1e-6

VALUES = np.array([-1e6, -30.0, -1.0, -0.02, -1e-9, 0.0, 1e-9, 0.02, 0.5, 1.0, 30.0, 1e6])


@pytest.fixture(params=DOMAIN_NAMES)
def bound(request):
    return Domain(request.param).bound(np.array([0.2, 0.6]))  # k = offset * 0.4


def test_offset_is_relative_to_the_mean_absolute_value():
    assert Domain("log").bound(np.array([-1.0, 3.0])).k == pytest.approx(0.1 * 2.0)
    assert Domain("log", offset=0.5, scale=4.0).bound(np.array([100.0])).k == pytest.approx(2.0)
    assert Domain("gamma").bound(np.zeros((3, 3))).k == pytest.approx(0.1)  # all-zero image: scale 1
    assert Domain("linear").bound(np.array([7.0])).k == 1.0


def test_inverse_undoes_forward(bound):
    assert_allclose(bound.inverse(bound.forward(VALUES)), VALUES, rtol=ROUND_TRIP_RTOL, atol=ROUND_TRIP_ATOL)


def test_transforms_are_odd_and_strictly_increasing(bound):
    y = bound.forward(VALUES)
    assert_array_equal(bound.forward(-VALUES), -y)
    assert (np.diff(y) > 0).all()
    assert bound.forward(np.array([0.0]))[0] == 0.0


def test_derivative_matches_central_differences(bound):
    x = VALUES[VALUES != 0]
    h = 1e-6 * (np.abs(x) + bound.k)
    numeric = (bound.forward(x + h) - bound.forward(x - h)) / (2 * h)
    assert_allclose(bound.derivative(x), numeric, rtol=DERIVATIVE_RTOL)
    assert (bound.derivative(VALUES) > 0).all()


def test_hand_checked_values():
    k = 0.1 * 0.4
    log = Domain("log").bound(np.array([0.2, 0.6]))
    assert log.forward(np.array([k]))[0] == pytest.approx(np.log(2.0), rel=1e-15)
    assert log.derivative(np.array([k]))[0] == pytest.approx(1.0 / (2 * k), rel=1e-15)
    gamma = Domain("gamma", gamma=2.0).bound(np.array([0.2, 0.6]))
    assert gamma.forward(np.array([3 * k]))[0] == pytest.approx(np.sqrt(4 * k) - np.sqrt(k), rel=1e-14)
    linear = Domain("linear").bound(np.array([1.0]))
    assert_array_equal(linear.forward(VALUES), VALUES)
    assert_array_equal(linear.variance(VALUES, np.abs(VALUES)), np.abs(VALUES))


def test_delta_method_variance(bound):
    mean = np.array([[0.1, 2.0], [-3.0, 0.0]])
    var = np.array([[0.01, 0.5], [1.0, 2.0]])
    assert_allclose(bound.variance(mean, var), var * bound.derivative(mean) ** 2, rtol=1e-15)


@pytest.mark.parametrize("name", ["log", "gamma"])
@pytest.mark.parametrize("a", [1e-6, 0.37, 1e6])
def test_log_is_scale_invariant_and_gamma_scale_equivariant(name, a):
    """With a relative offset, scaling the image by a scales y by 1 (log) or a^(1/gamma) (gamma)."""
    mean = np.array([0.05, 0.3, 2.0, 30.0])
    d0, d1 = Domain(name).bound(mean), Domain(name).bound(a * mean)
    power = 0.0 if name == "log" else 1.0 / Domain().gamma
    assert_allclose(d1.forward(a * mean), a**power * d0.forward(mean), rtol=1e-12)
    assert_allclose(d1.variance(a * mean, a * a * mean), a ** (2 * power) * d0.variance(mean, mean), rtol=1e-12)


def test_log_inverse_saturates_instead_of_overflowing():
    log = Domain("log").bound(np.array([1.0]))
    out = log.inverse(np.array([-1e4, 800.0, 1e4]))
    assert np.isfinite(out).all() and out[0] < 0 < out[1]


def test_robust_derivative_is_taken_below_an_isolated_spike():
    mean = np.full((5, 5), 0.5)
    mean[2, 2] = 50.0  # a firefly
    var = np.full((5, 5), 1.0)
    plain = Domain("log").bound(mean).variance(mean, var)
    robust = Domain("log", robust=True).bound(mean).variance(mean, var)
    assert robust[2, 2] > 1000 * plain[2, 2]  # the spike keeps the variance of its surroundings
    assert_allclose(np.delete(robust.ravel(), 12), np.delete(plain.ravel(), 12), rtol=1e-15)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"name": "sqrt"}, "domain: 'sqrt'"),
    ({"offset": 0.0}, "domain offset"),
    ({"offset": np.inf}, "domain offset"),
    ({"gamma": 0.5}, "domain gamma"),
    ({"scale": -1.0}, "domain scale"),
])
def test_bad_parameters_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Domain(**kwargs)


def test_resolve_domain():
    assert resolve_domain("gamma") == Domain("gamma")
    d = Domain("log", offset=0.3)
    assert resolve_domain(d) is d
    with pytest.raises(TypeError, match="domain"):
        resolve_domain(3)


@pytest.mark.parametrize("k", [1e6, 1e18, 1e40])
def test_gamma_resolves_pixels_far_below_its_offset(k):
    """``(x + k)^p - k^p`` cancelled to nothing for x far below k (a light 1e18 times the background
    set k: the background came back as 3 or -288, a red-team pass). Written as ``k^p expm1(p log1p(x / k))``
    the forward map is ``p k^(p - 1) x`` to first order, and the inverse returns x."""
    bound = Domain("gamma", gamma=2.0, scale=k / 0.1).bound(np.array([1.0]))
    assert bound.k == pytest.approx(k)
    x = np.array([0.5, 3.0, 1e-3])
    y = bound.forward(x)
    assert_allclose(y, 0.5 * k**-0.5 * x, rtol=1e-6)
    assert_allclose(bound.inverse(y), x, rtol=1e-12)


@pytest.mark.parametrize("name", ["log", "gamma"])
@pytest.mark.parametrize("top", [1.65e308, 1.7e308, np.finfo(np.float64).max])
def test_domains_take_means_up_to_the_largest_float(name, top):
    """``|x| + k`` overflowed for means near 1.7e308: the gamma domain refused them as "NaN or Inf", its
    derivative (and the log domain's) was 0 there (a red-team pass)."""
    x = np.array([0.5 * top, top])
    bound = Domain(name).bound(x)
    y, d = bound.forward(x), bound.derivative(x)
    assert np.isfinite(y).all() and np.isfinite(d).all() and (d > 0).all()
    assert_allclose(bound.inverse(y), x, rtol=1e-12)


@pytest.mark.parametrize("name", ["log", "gamma"])
def test_a_scale_far_below_the_image_keeps_the_domain_finite(name):
    """``|x| / k`` past float64 (a scale of 1e-300 beside means of 1e10) gave y = Inf."""
    bound = Domain(name, scale=1e-300).bound(np.array([1.0]))
    x = np.array([1e10, 1e300])
    y = bound.forward(x)
    assert np.isfinite(y).all()
    assert_allclose(bound.inverse(y), x, rtol=1e-10)


def test_a_nan_beside_an_overflowing_ratio_stays_nan_alone():
    """The overflow fallback was skipped when the plane's maximum was NaN: an Inf left beside it."""
    bound = Domain("log", scale=1e-299).bound(np.array([1.0]))
    y = bound.forward(np.array([np.nan, 1e10, 1.0]))
    assert np.isnan(y[0]) and np.isfinite(y[1:]).all()
    assert np.isnan(bound.derivative(np.array([np.nan, 1.7e308]))[0])
