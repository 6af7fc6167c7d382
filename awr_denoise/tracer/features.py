"""Per-sample features of the path tracer: albedo, shading normal and depth (docs/tracer.md, "Features").

Which hit each feature describes, following Intel Open Image Denoise's documentation (its
``albedo`` and ``normal`` inputs):

* ``depth`` is the camera-space z (distance from the camera plane along the view axis) of the
  first surface the camera ray hits, 0 when it hits nothing.
* ``albedo`` and ``normal`` follow perfect mirrors (delta BSDFs) and describe the first
  diffuse, glossy or emitting hit behind them: the albedo there times the reflectances of the
  mirrors on the way, the shading normal there (world space, unit length, facing the ray).
  A path that ends at a mirror (the specular depth limit) keeps the last mirror's. A ray that
  escapes has albedo 0 and normal 0 (OIDN's convention for "no surface"). Emitters reflect
  nothing in this tracer: their albedo is 0.

Features draw no random numbers, so rendering them leaves every radiance sample unchanged.
"""

from __future__ import annotations

import numpy as np

from ..features import feature_names

__all__ = ["FeatureRecorder"]


class FeatureRecorder:
    """The features of a wavefront of ``n`` camera samples, filled in bounce by bounce.

    Parameters
    ----------
    n
        Number of samples.
    names
        Features to report (:data:`~awr_denoise.features.FEATURE_NAMES`).
    origin, forward
        The camera's position and unit viewing direction (world space), for ``depth``.

    Examples
    --------
    A camera ray hits a mirror (reflectance 0.5), then a diffuse wall of albedo 0.8:

    >>> import numpy as np
    >>> record = FeatureRecorder(1, ("albedo", "normal", "depth"), np.zeros(3), np.array([0.0, 0.0, 1.0]))
    >>> paths = np.array([0])
    >>> record.camera_hits(paths, np.array([[0.0, 1.0, 3.0]]))
    >>> record.surfaces(paths, np.array([[0.0, 0.0, -1.0]]), np.full((1, 3), 0.5), np.array([True]))
    >>> record.surfaces(paths, np.array([[1.0, 0.0, 0.0]]), np.full((1, 3), 0.8), np.array([False]))
    >>> {k: v.ravel().tolist() for k, v in record.values().items()}
    {'albedo': [0.4, 0.4, 0.4], 'normal': [1.0, 0.0, 0.0], 'depth': [3.0]}
    """

    def __init__(self, n: int, names: tuple[str, ...], origin: np.ndarray, forward: np.ndarray) -> None:
        self.names = feature_names(names)
        self.origin = np.asarray(origin, float)
        self.forward = np.asarray(forward, float)
        self.albedo = np.zeros((n, 3))
        self.normal = np.zeros((n, 3))
        self.depth = np.zeros(n)
        self.open = np.ones(n, bool)   # still behind mirrors only: albedo and normal not final
        self.tint = np.ones((n, 3))    # product of the mirror reflectances passed

    def camera_hits(self, paths: np.ndarray, points: np.ndarray) -> None:
        """Depth of the first hits of camera rays (``paths`` index the samples)."""
        self.depth[paths] = (points - self.origin) @ self.forward

    def misses(self, paths: np.ndarray) -> None:
        """Rays of ``paths`` escaped: samples still open get albedo 0 and normal 0."""
        still = paths[self.open[paths]]
        self.albedo[still] = 0.0
        self.normal[still] = 0.0
        self.open[still] = False

    def surfaces(self, paths: np.ndarray, normals: np.ndarray, reflectance: np.ndarray, delta: np.ndarray) -> None:
        """Hits of ``paths`` with their shading ``normals``, ``reflectance`` (RGB) and delta flag."""
        sel = self.open[paths]
        p = paths[sel]
        self.albedo[p] = np.clip(self.tint[p] * reflectance[sel], 0.0, 1.0)
        self.normal[p] = normals[sel]
        through = delta[sel]
        self.tint[p[through]] *= reflectance[sel][through]
        self.open[p[~through]] = False

    def values(self) -> dict[str, np.ndarray]:
        """``{name: (n, channels)}`` per-sample values of the requested features."""
        every = {"albedo": self.albedo, "normal": self.normal, "depth": self.depth[:, None]}
        return {name: every[name] for name in self.names}
