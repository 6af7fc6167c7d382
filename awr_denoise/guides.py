"""Guide images for :func:`~awr_denoise.reconstruct`: a neural denoiser's view of the same samples.

A guide is an (H, W, C) estimate of the clean image that the reconstruction uses to choose how
much to shrink each wavelet coefficient of the pixel means, and follows only within three
standard errors of each coefficient (:mod:`awr_denoise.guided`, :mod:`awr_denoise.projection`), so
the result stays, coefficient by coefficient, within what the samples allow. The guides here
need optional extras, imported when first used:

``oidn``
    Intel Open Image Denoise (extra ``oidn``, the ``pyoidn`` bindings): its ``RT`` filter on the
    pixel means, with the buffer's albedo and normal features when it carries them, denoised first
    by OIDN's own filters for them (its documented way with noisy auxiliary images).

Pass the function itself as the guide and the reconstruction calls it on the buffer it denoises
(``reconstruct(buffer, guide=guides.oidn)``), or call it and pass its image. :class:`OIDNGuide` is
the same function with its settings, which the result records (``awr denoise --guide oidn``).
"""

from __future__ import annotations

import atexit
import math
import os
import threading
from collections.abc import Collection
from dataclasses import dataclass
from typing import Any

import numpy as np

from ._arrays import numeric
from ._typing import FloatArray
from .buffers import SampleBuffer
from .errors import BackendError, BackendUnavailableError
from .guided import guide_colour
from .prepare import filled_mean

__all__ = ["oidn", "oidn_available", "oidn_features", "OIDNGuide", "OIDN_HINT", "GUIDES", "AUXILIARY", "QUALITIES"]

OIDN_HINT = 'the OIDN guide needs pyoidn (Intel Open Image Denoise); install it with pip install "awr-denoise[oidn]"'
"""What to install when :func:`oidn` cannot import ``pyoidn``."""

_FLOAT32_MAX = float(np.finfo(np.float32).max)

AUXILIARY = ("prefilter", "noisy", "clean", "none")
"""How :func:`oidn` treats the albedo and normal (OIDN's three ways, and a fourth): denoised first by OIDN's
filters for them, then taken as clean (``"prefilter"``, the default); as they are, known to be noisy
(``"noisy"``); as they are, noise-free (``"clean"``); left out, OIDN on the colour alone (``"none"``)."""

QUALITIES = ("high", "balanced", "fast")
"""OIDN's filter qualities (:func:`oidn`'s ``quality``)."""

_oidn: dict[Any, Any] = {}  # OIDN's device and its filters, made once: each filter loads its network's weights
_oidn_lock = threading.Lock()  # one image at a time through them (they hold the images they are given)


def oidn_available() -> bool:
    """Whether ``pyoidn`` imports. Its native library loads when first used: should it fail then,
    :func:`oidn` raises :class:`~awr_denoise.errors.BackendUnavailableError`.

    Examples
    --------
    >>> from awr_denoise.guides import oidn_available
    >>> isinstance(oidn_available(), bool)
    True
    """
    try:
        import pyoidn  # noqa: F401 - optional extra "oidn", imported lazily
    except Exception:  # noqa: BLE001 - a missing native library is as good as a missing package
        return False
    return True


def _auxiliary(name: str, given: object, buffer: SampleBuffer, low: float, high: float) -> np.ndarray | None:
    """An albedo or normal image for OIDN: the one given, else the buffer's feature, checked."""
    if given is None:
        if name not in buffer.features:
            return None
        given = buffer.features[name].mean
    try:
        image = numeric(name, given).astype(np.float64)  # complex, bool, object and masked entries refused
    except ValueError as error:  # ragged lists
        raise ValueError(f"{name}: expected an (H, W, 3) array of numbers ({error})") from None
    if image.shape != (*buffer.shape, 3):
        raise ValueError(f"{name}: shape {image.shape} does not match the buffer's {(*buffer.shape, 3)}")
    if not np.isfinite(image).all():
        raise ValueError(f"{name}: {int((~np.isfinite(image)).sum())} values are NaN or infinite")
    return np.ascontiguousarray(np.clip(image, low, high), dtype=np.float32)


def oidn(buffer: SampleBuffer, albedo: FloatArray | None = None, normal: FloatArray | None = None, *,
         quality: str = "high", auxiliary: str = "prefilter") -> FloatArray:
    """Intel Open Image Denoise's ``RT`` filter on the pixel means (HDR), as a guide.

    Parameters
    ----------
    buffer
        The samples: three channels, or one three-channel colour beside an alpha or an AOV, whose
        guide this is (:func:`~awr_denoise.guided.checked_guide`). Channels named R, G and B go to
        OIDN in that order. Pixels without samples take their nearest neighbour's mean, negative
        means count as 0 (OIDN takes non-negative HDR colour).
    albedo, normal
        (H, W, 3) auxiliary images; by default the buffer's ``albedo`` and ``normal`` features
        when it carries them (:mod:`awr_denoise.features`). Clipped to OIDN's ranges ([0, 1]
        and [-1, 1]). OIDN takes a normal only with an albedo.
    quality
        OIDN's filter quality: ``"high"`` (default), ``"balanced"`` or ``"fast"``.
    auxiliary
        How OIDN treats them (:data:`AUXILIARY`): ``"prefilter"`` (default) denoises each with OIDN's filter for it
        first, then gives them as clean; ``"noisy"`` gives them as they are, noisy; ``"clean"`` as they are, noise-free
        (a separate render of many samples); ``"none"`` leaves them out (the buffer's and those given alike). OIDN takes
        them as clean only as a pair: an albedo without a normal it takes as noisy, prefiltered or not. Features
        averaged over the radiance's few samples are noisy where a lens, a texture or an edge varies within the pixel:
        prefiltered, the guided reconstruction's relMSE is 0.52-1.05x that with them given as noisy on the bundled
        tracer's and Mitsuba 3's scenes at 8-32 spp, lowest on the defocused and textured ones (docs/guides.md, "The
        albedo and normal, prefiltered").

    Returns
    -------
    numpy.ndarray
        The (H, W, 3) denoised colour, float64, its channels in the buffer's order.

    Raises
    ------
    ImportError
        ``pyoidn`` is not installed (extra ``oidn``); the message says what to install.
    ValueError
        No three-channel colour, a normal without an albedo, bad auxiliary images, or an unknown
        ``quality`` or ``auxiliary``.
    awr_denoise.errors.BackendError
        OIDN itself failed (its device, a filter, or values that are not finite); its message is kept.
        A ``RuntimeError``; :class:`~awr_denoise.errors.BackendUnavailableError` when its library
        does not load.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer, reconstruct
    >>> from awr_denoise import guides
    >>> rng = np.random.default_rng(0)
    >>> mean = 0.5 + 0.1 * rng.standard_normal((32, 32, 3))
    >>> buffer = SampleBuffer.from_moments(np.full((32, 32), 8), mean, np.full((32, 32, 3), 0.08))
    >>> if guides.oidn_available():  # the extra "oidn"
    ...     guide = guides.oidn(buffer)
    ...     out = reconstruct(buffer, guide=guide)
    ...     assert guide.shape == out.shape == (32, 32, 3)
    """
    if not isinstance(buffer, SampleBuffer):  # an image instead of the samples: say so, not "no attribute"
        raise TypeError(f"buffer: expected a SampleBuffer, got {type(buffer).__name__}")
    order, back = _rgb(buffer)
    _checked_settings(quality, auxiliary)
    if normal is not None and albedo is None and "albedo" not in buffer.features:
        raise ValueError("normal: OIDN takes a normal image only with an albedo image")
    alb = _auxiliary("albedo", albedo, buffer, 0.0, 1.0)
    nrm = _auxiliary("normal", normal, buffer, -1.0, 1.0) if alb is not None else None
    if auxiliary == "none":  # checked above all the same: a bad image given is a mistake whatever the mode
        alb = nrm = None
    try:
        import pyoidn  # optional extra "oidn", imported lazily
    except ImportError as error:
        raise ImportError(OIDN_HINT) from error
    mean = filled_mean(buffer)[..., order]
    # OIDN denoises float32 in HDR: means past 2**64 or below 2**-64 are brought in by a power of two
    # and back, the same image bit for bit (at 1e100 they were clipped: garbage; tests/test_guides.py).
    # The array is scaled by its exponent, not multiplied by 2**-e, which passes float64 for subnormal means.
    top = float(np.max(mean, initial=0.0))
    power = math.frexp(top)[1] if top > 0 and not 2.0**-64 <= top <= 2.0**64 else 0
    colour = np.ascontiguousarray(np.clip(np.ldexp(mean, -power), 0.0, _FLOAT32_MAX), dtype=np.float32)
    images = {"color": colour, "albedo": alb, "normal": nrm}
    with _oidn_lock:
        if alb is not None and auxiliary == "prefilter":
            images["albedo"] = _filtered(pyoidn, ("albedo",), {"albedo": alb}, quality, {}, (0.0, 1.0))
            if nrm is not None:
                images["normal"] = _filtered(pyoidn, ("normal",), {"normal": nrm}, quality, {}, (-1.0, 1.0))
        given = tuple(name for name, image in images.items() if image is not None)
        flags = {"hdr": True, "cleanAux": alb is not None and auxiliary != "noisy"}
        out = _filtered(pyoidn, given, {n: images[n] for n in given}, quality, flags, (0.0, _FLOAT32_MAX))
    return np.ldexp(out.astype(np.float64), power)[..., back]


def _filtered(pyoidn: Any, inputs: tuple[str, ...], images: dict[str, np.ndarray], quality: str,
              flags: dict[str, bool], clip: tuple[float, float]) -> np.ndarray:
    """OIDN's ``RT`` filter on ``images`` (its ``color`` with ``albedo``/``normal``, or one auxiliary image alone,
    which it then denoises as an auxiliary image), clipped to ``clip``. Under ``_oidn_lock``: the device and one
    filter per set of inputs are made once (each loads its network's weights) and hold the images given."""
    if "device" not in _oidn:
        try:
            device = pyoidn.Device()  # pyoidn loads OIDN's library here, when first used
        except OSError as error:
            raise BackendUnavailableError(f"OIDN cannot start: its library did not load ({error}); reinstall the "
                                          'extra: pip install --force-reinstall "awr-denoise[oidn]"') from error
        device.commit()
        try:
            _raise_oidn_error(device, "device")
        except RuntimeError:
            device.release()
            raise
        _oidn["device"] = device
    device = _oidn["device"]
    what = "+".join(inputs)
    if inputs not in _oidn:
        _oidn[inputs] = pyoidn.Filter(device, pyoidn.OIDN_FILTER_TYPE_RT)  # a failed one is released below
    flt = _oidn[inputs]
    first = images[inputs[0]]
    result = np.full_like(first, np.nan)  # never the memory's leftovers, should OIDN write nothing
    try:
        _raise_oidn_error(device, what)  # a filter never made holds no weights
        for name in inputs:
            flt.set_image(name, images[name], pyoidn.OIDN_FORMAT_FLOAT3)
        flt.set_image(pyoidn.OIDN_IMAGE_OUTPUT, result, pyoidn.OIDN_FORMAT_FLOAT3)
        for name, value in flags.items():
            flt.set_bool(name, value)
        flt.set_quality(getattr(pyoidn, f"OIDN_QUALITY_{quality.upper()}"))
        flt.commit()
        flt.execute()
        _raise_oidn_error(device, what)
        if not np.isfinite(result).all():
            raise BackendError(f"OIDN {what} failed: it left values that are not finite")
    except RuntimeError as error:  # the device's error, or the bindings' own
        _oidn.pop(inputs).release()  # made again next time, not reused in a state it failed in
        if isinstance(error, BackendError):
            raise
        raise BackendError(f"OIDN {what} failed: {error}") from error
    return np.clip(result, *clip)


def _raise_oidn_error(device: Any, what: str) -> None:
    error = device.get_error()
    if error is not None:
        raise BackendError(f"OIDN {what} failed: {error}")


def _release_oidn() -> None:
    """Filters before their device, at exit (as pyoidn releases its own); nothing when none was made."""
    with _oidn_lock:
        for key in sorted(_oidn, key=lambda k: k == "device"):  # the device last
            _oidn.pop(key).release()


atexit.register(_release_oidn)


def _forget_oidn() -> None:
    """In a child process made by ``fork``: the parent's device and its threads are not the child's (using them
    hung for ever), nor is a lock another thread of the parent held. The child makes its own when it needs them."""
    global _oidn_lock
    _oidn.clear()
    _oidn_lock = threading.Lock()


if hasattr(os, "register_at_fork"):  # POSIX
    os.register_at_fork(after_in_child=_forget_oidn)


def _rgb(buffer: SampleBuffer) -> tuple[list[int], list[int]]:
    """The buffer's channels OIDN denoises, in R, G, B order where they are so named, and the order
    that puts OIDN's result back in the buffer's: its three channels, or its only colour beside an
    alpha or an AOV (:func:`~awr_denoise.guided.guide_colour`)."""
    group = guide_colour(buffer) or (tuple(range(3)) if buffer.n_channels == 3 else None)
    if group is None or len(group) != 3:
        raise ValueError(f"buffer: OIDN (guides.oidn / --guide oidn) denoises one three-channel colour (R,G,B); this "
                         f"buffer's channels are {','.join(buffer.channels)}")
    bare = [buffer.channels[i].rsplit(".", 1)[-1].upper() for i in group]
    order = [group[bare.index(c)] for c in "RGB"] if sorted(bare) == ["B", "G", "R"] else list(group)
    return order, [order.index(i) for i in group]


def _checked_settings(quality: object, auxiliary: object) -> None:
    if not isinstance(quality, str) or quality not in QUALITIES:
        raise ValueError(f"quality: {quality!r} is not one of {', '.join(QUALITIES)}")
    if not isinstance(auxiliary, str) or auxiliary not in AUXILIARY:
        raise ValueError(f"auxiliary: {auxiliary!r} is not one of {', '.join(AUXILIARY)}")


@dataclass(frozen=True)
class OIDNGuide:
    """:func:`oidn` with its settings, as a guide whose settings the reconstruction records.

    Called on a buffer it is ``oidn(buffer, quality=quality, auxiliary=auxiliary)``; given as
    :func:`~awr_denoise.reconstruct` 's ``guide`` it adds :meth:`recorded` to the result's
    ``parameters`` (an image's ``awr:`` header: ``awr:guide_auxiliary``, ``awr:guide_quality``).
    The settings are checked when it is made, before any work; it pickles (a process pool, Dask).
    :func:`oidn` itself records what ``OIDNGuide()`` does.

    Examples
    --------
    >>> import numpy as np
    >>> from awr_denoise import SampleBuffer
    >>> from awr_denoise.guides import OIDNGuide
    >>> buffer = SampleBuffer.from_moments(np.ones((2, 2)), np.ones((2, 2, 3)), np.zeros((2, 2, 3)))
    >>> OIDNGuide(auxiliary="noisy").recorded(buffer)    # no albedo: OIDN takes the colour alone
    {'guide_auxiliary': 'none', 'guide_quality': 'high'}
    >>> OIDNGuide(auxiliary="dirty")
    Traceback (most recent call last):
    ...
    ValueError: auxiliary: 'dirty' is not one of prefilter, noisy, clean, none
    """

    auxiliary: str = "prefilter"
    quality: str = "high"

    def __post_init__(self) -> None:
        _checked_settings(self.quality, self.auxiliary)

    def __call__(self, buffer: SampleBuffer) -> FloatArray:
        return oidn(buffer, quality=self.quality, auxiliary=self.auxiliary)

    def recorded(self, buffer: SampleBuffer) -> dict[str, str]:
        """What the reconstruction of ``buffer`` records of the guide: the way OIDN takes the albedo and
        normal, ``"none"`` where the buffer carries no albedo (OIDN then takes the colour alone), and
        ``"noisy"`` for ``"clean"`` where it carries no normal (OIDN takes them as clean only as a pair)."""
        auxiliary = self.auxiliary
        if "albedo" not in buffer.features:
            auxiliary = "none"
        elif auxiliary == "clean" and "normal" not in buffer.features:
            auxiliary = "noisy"
        return {"guide_auxiliary": auxiliary, "guide_quality": self.quality}


def oidn_features(features: Collection[str], auxiliary: str | None = "prefilter") -> tuple[str, ...]:
    """The features OIDN takes from a buffer that carries ``features``: the albedo, and the normal beside it (OIDN
    takes a normal only with an albedo); none with ``auxiliary="none"``, and never the depth.

    Examples
    --------
    >>> from awr_denoise.guides import oidn_features
    >>> oidn_features(("albedo", "normal", "depth")), oidn_features(("normal",)), oidn_features(("albedo",), "none")
    (('albedo', 'normal'), (), ())
    """
    if auxiliary == "none" or "albedo" not in features:
        return ()
    return tuple(name for name in ("albedo", "normal") if name in features)


def _oidn_recorded(buffer: SampleBuffer) -> dict[str, str]:
    return OIDNGuide().recorded(buffer)


oidn.recorded = _oidn_recorded  # type: ignore[attr-defined]  # guide=guides.oidn records its defaults too

GUIDES = {"oidn": OIDNGuide()}
"""The guides by name (``awr denoise --guide NAME``), with their default settings."""
