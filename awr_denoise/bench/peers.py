"""Peer denoisers the benchmark compares AWR with, on the same uniform buffers.

Both are optional extras, imported when first used: scikit-image (extra ``bench``) and Intel
Open Image Denoise's Python bindings ``pyoidn`` (extra ``oidn``).
"""

from __future__ import annotations

import numpy as np

from .._typing import FloatArray

__all__ = ["skimage_denoise", "oidn_available", "oidn_denoise", "require_skimage", "SKIMAGE_HINT", "OIDN_HINT"]

SKIMAGE_HINT = 'the benchmark needs scikit-image; install it with pip install "awr-denoise[bench]"'
OIDN_HINT = 'the OIDN peer needs pyoidn; install it with pip install "awr-denoise[oidn]"'


def require_skimage() -> None:
    """Raise :class:`ImportError` with the install hint when scikit-image is missing.

    Raises
    ------
    ImportError
        scikit-image (extra ``bench``) does not import.
    """
    try:
        import skimage  # noqa: F401 - optional extra "bench", imported lazily
    except ImportError as exc:
        raise ImportError(SKIMAGE_HINT) from exc


def skimage_denoise(mean: FloatArray) -> FloatArray:
    """scikit-image's ``denoise_wavelet`` (BayesShrink, soft) applied to an HDR image.

    BayesShrink estimates one noise level per channel from the image itself (median absolute
    deviation of the finest diagonal band) and assumes it is the same everywhere, which holds
    for neither radiance nor its tonemapped version. The image is therefore denoised in the
    same log domain AWR uses by default, ``y = log(1 + x / k)`` with ``k = 0.1 * mean|x|``, where
    Monte Carlo noise is closer to homoscedastic, and mapped back with ``x = k (e^y - 1)``.
    Wavelet ``db1`` with scikit-image's default depth, ``rescale_sigma=True``.

    Parameters
    ----------
    mean
        The noisy image, ``(H, W, 3)``.

    Returns
    -------
    numpy.ndarray
        The denoised image, float64, non-negative.

    Raises
    ------
    ImportError
        scikit-image (extra ``bench``) is not installed.
    """
    try:
        from skimage.restoration import denoise_wavelet  # optional extra "bench", imported lazily
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(SKIMAGE_HINT) from exc
    x = np.maximum(np.asarray(mean, dtype=np.float64), 0.0)
    k = 0.1 * float(np.mean(x)) if np.mean(x) > 0 else 1.0
    y = np.log1p(x / k)
    out = denoise_wavelet(y, method="BayesShrink", mode="soft", wavelet="db1", channel_axis=-1, rescale_sigma=True)
    return k * np.expm1(np.maximum(out, 0.0))


def oidn_available() -> bool:
    """Whether Intel Open Image Denoise's Python bindings (``pyoidn``) import.

    Returns
    -------
    bool
        False on any failure to load them (the package or its native library missing).
    """
    try:
        import pyoidn  # noqa: F401 - optional extra "oidn", imported lazily
    except Exception:  # noqa: BLE001 - any failure to load the native library means "skip"
        return False
    return True


def oidn_denoise(mean: FloatArray) -> FloatArray:
    """Intel Open Image Denoise (``pyoidn``, filter ``RT``, ``hdr=True``, quality ``high``).

    Colour only: the benchmark's buffers carry no albedo or normal, which OIDN would use as
    auxiliary features (docs/guides.md compares OIDN with them, on the tracer's and Mitsuba's scenes).

    Parameters
    ----------
    mean
        The noisy HDR image, ``(H, W, 3)``.

    Returns
    -------
    numpy.ndarray
        The denoised image, float64.

    Raises
    ------
    ImportError
        ``pyoidn`` (extra ``oidn``) is not installed; check with :func:`oidn_available`.
    """
    try:
        import pyoidn  # optional extra "oidn", imported lazily
    except ImportError as exc:
        raise ImportError(OIDN_HINT) from exc

    x = np.ascontiguousarray(np.maximum(mean, 0.0), dtype=np.float32)
    return np.asarray(pyoidn.denoise(x, hdr=True, quality="high"), dtype=np.float64)
