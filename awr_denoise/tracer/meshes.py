"""Procedural triangle meshes and small vector helpers, all vectorised over arrays of vectors.

Every mesh generator returns ``(vertices, faces, normals)``: float64 (V, 3) positions, int64
(F, 3) counter-clockwise faces (the geometric normal ``cross(v1 - v0, v2 - v0)`` points
outwards) and float64 (V, 3) per-vertex shading normals.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "Mesh",
    "normalize",
    "dot",
    "cross",
    "coordinate_frame",
    "rotation_matrices",
    "sphere_mesh",
    "box_mesh",
    "quad_mesh",
    "lathe_mesh",
    "CHESS_PROFILES",
]

Mesh = tuple[np.ndarray, np.ndarray, np.ndarray]


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of (N, 3) arrays (broadcasts)."""
    return np.einsum("...i,...i->...", a, b)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product (faster than ``np.cross`` for (N, 3) arrays)."""
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def normalize(v: np.ndarray) -> np.ndarray:
    """Unit vectors; zero vectors stay zero instead of becoming NaN."""
    length = np.sqrt(dot(v, v))
    return v / np.where(length > 0, length, 1.0)[..., None]


def coordinate_frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two tangents completing unit normals ``n`` to orthonormal frames.

    Branchless construction of Duff et al. 2017, "Building an Orthonormal Basis, Revisited".
    """
    sign = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    s = np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * b, -sign * n[:, 0]], axis=-1)
    t = np.stack([b, sign + n[:, 1] ** 2 * a, -n[:, 1]], axis=-1)
    return s, t


def rotation_matrices(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices about a unit ``axis`` by ``angle`` radians (Rodrigues)."""
    angle = np.asarray(angle, dtype=np.float64)
    x, y, z = (float(c) for c in axis)
    c, s = np.cos(angle), np.sin(angle)
    one_c = 1.0 - c
    m = np.empty(angle.shape + (3, 3))
    m[..., 0, 0] = c + x * x * one_c
    m[..., 0, 1] = x * y * one_c - z * s
    m[..., 0, 2] = x * z * one_c + y * s
    m[..., 1, 0] = y * x * one_c + z * s
    m[..., 1, 1] = c + y * y * one_c
    m[..., 1, 2] = y * z * one_c - x * s
    m[..., 2, 0] = z * x * one_c - y * s
    m[..., 2, 1] = z * y * one_c + x * s
    m[..., 2, 2] = c + z * z * one_c
    return m


def sphere_mesh(center: np.ndarray, radius: float, *, segments: int = 48, rings: int = 24) -> Mesh:
    """UV sphere with smooth normals; ``segments`` around the y axis, ``rings`` from pole to pole."""
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)[:-1]
    t, p = np.meshgrid(theta, phi, indexing="ij")
    normals = np.stack([np.sin(t) * np.cos(p), np.cos(t), -np.sin(t) * np.sin(p)], axis=-1).reshape(-1, 3)
    vertices = np.asarray(center, np.float64) + radius * normals
    faces = []
    for r in range(rings):
        for s in range(segments):
            a = r * segments + s
            b = r * segments + (s + 1) % segments
            c = (r + 1) * segments + s
            d = (r + 1) * segments + (s + 1) % segments
            if r > 0:
                faces.append((a, c, b))
            if r < rings - 1:
                faces.append((b, c, d))
    return vertices, np.asarray(faces, np.int64), normals


def quad_mesh(corner: np.ndarray, edge_u: np.ndarray, edge_v: np.ndarray) -> Mesh:
    """Parallelogram ``corner + a edge_u + b edge_v``; its normal is ``cross(edge_u, edge_v)``."""
    corner, edge_u, edge_v = (np.asarray(x, np.float64) for x in (corner, edge_u, edge_v))
    vertices = np.stack([corner, corner + edge_u, corner + edge_u + edge_v, corner + edge_v])
    normal = normalize(np.cross(edge_u, edge_v)[None])[0]
    faces = np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    return vertices, faces, np.tile(normal, (4, 1))


def box_mesh(minimum: np.ndarray, maximum: np.ndarray) -> Mesh:
    """Axis-aligned box with flat faces and outward normals."""
    lo, hi = np.asarray(minimum, np.float64), np.asarray(maximum, np.float64)
    size = hi - lo
    ex, ey, ez = np.diag(size)
    quads = [
        (lo, ey, ex),                 # -z face
        (lo + ez, ex, ey),            # +z
        (lo, ez, ey),                 # -x
        (lo + ex, ey, ez),            # +x
        (lo, ex, ez),                 # -y
        (lo + ey, ez, ex),            # +y
    ]
    parts = [quad_mesh(c, u, v) for c, u, v in quads]
    return _concatenate(parts)


def lathe_mesh(profile: np.ndarray, base: np.ndarray, scale: float = 1.0, *, segments: int = 48) -> Mesh:
    """Surface of revolution about the vertical axis through ``base``.

    ``profile`` is a (K, 2) polyline of (radius, height) from bottom to top; a radius of 0 at
    either end closes the surface. Normals are smoothed along each ring and down the profile,
    except where the profile turns by more than 60 degrees (a crease, like a piece's collar).
    """
    profile = np.asarray(profile, np.float64) * scale
    radius, height = profile[:, 0], profile[:, 1]
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)[:-1]
    cos_phi, sin_phi = np.cos(phi), -np.sin(phi)
    # 2D outward normals of each profile segment (perpendicular to the segment direction).
    seg = np.diff(profile, axis=0)
    seg_normal = normalize(np.stack([seg[:, 1], -seg[:, 0]], axis=-1))
    vertices, faces, normals = [], [], []
    count = 0
    for k in range(len(seg)):  # one band of quads per profile segment
        n2 = seg_normal[k]
        ring = []
        for end in (k, k + 1):
            pos = np.stack([radius[end] * cos_phi, np.full_like(phi, height[end]), radius[end] * sin_phi], -1)
            # Smooth with the neighbouring segment unless the profile creases there.
            other = k - 1 if end == k else k + 1
            n_end = n2
            if 0 <= other < len(seg) and np.dot(seg_normal[other], n2) > 0.5:
                n_end = normalize((seg_normal[other] + n2)[None])[0]
            nrm = np.stack([n_end[0] * cos_phi, np.full_like(phi, n_end[1]), n_end[0] * sin_phi], -1)
            ring.append((pos, nrm))
        vertices += [ring[0][0], ring[1][0]]
        normals += [ring[0][1], ring[1][1]]
        i = np.arange(segments)
        j = (i + 1) % segments
        a, b = count + i, count + j
        c, d = count + segments + i, count + segments + j
        band = []
        if radius[k] > 0:
            band.append(np.stack([a, b, d], -1))
        if radius[k + 1] > 0:
            band.append(np.stack([a, d, c], -1))
        faces += band
        count += 2 * segments
    v = np.concatenate(vertices) + np.asarray(base, np.float64)
    return v, np.concatenate(faces).astype(np.int64), normalize(np.concatenate(normals))


def _concatenate(parts: list[Mesh]) -> Mesh:
    vertices, faces, normals, offset = [], [], [], 0
    for v, f, n in parts:
        vertices.append(v)
        faces.append(f + offset)
        normals.append(n)
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(faces), np.concatenate(normals)


# Chess-like piece profiles, (radius, height) in units of the piece's base radius.
CHESS_PROFILES: dict[str, list[tuple[float, float]]] = {
    "pawn": [(0.0, 0.0), (1.0, 0.0), (1.0, 0.18), (0.8, 0.3), (0.5, 0.4), (0.35, 1.0), (0.6, 1.08),
             (0.6, 1.16), (0.3, 1.22), (0.5, 1.35), (0.55, 1.5), (0.45, 1.7), (0.25, 1.8), (0.0, 1.84)],
    "bishop": [(0.0, 0.0), (1.0, 0.0), (1.0, 0.2), (0.8, 0.32), (0.45, 0.45), (0.3, 1.5), (0.6, 1.58),
               (0.6, 1.66), (0.3, 1.72), (0.45, 1.95), (0.42, 2.2), (0.2, 2.45), (0.12, 2.55),
               (0.16, 2.62), (0.0, 2.7)],
    "king": [(0.0, 0.0), (1.05, 0.0), (1.05, 0.22), (0.85, 0.35), (0.5, 0.5), (0.36, 2.0), (0.7, 2.1),
             (0.7, 2.2), (0.4, 2.28), (0.62, 2.75), (0.62, 2.85), (0.2, 2.9), (0.2, 3.25), (0.0, 3.3)],
    "rook": [(0.0, 0.0), (1.0, 0.0), (1.0, 0.22), (0.8, 0.35), (0.55, 0.5), (0.5, 1.4), (0.75, 1.5),
             (0.75, 1.9), (0.55, 1.9), (0.55, 1.75), (0.0, 1.75)],
}
