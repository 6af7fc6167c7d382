"""Ray queries on embreex: static geometry plus rigidly moving objects.

Embree via embreex has no motion blur and a fixed ``tnear = 0`` (see the ecosystem notes,
section 3). Static objects share one ``EmbreeScene``; every moving object gets its own scene in
object space, rays are mapped into it with the inverse of the object's transform at each ray's
time, and the nearest hit over all scenes wins (rigid maps keep ray parameters, so ``tfar``
values compare directly). Hit points are rebuilt in float64 from the barycentrics returned by
Embree, which is more precise than ``o + tfar d`` in float32.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from .meshes import cross, normalize
from .scene import Scene

__all__ = ["Accelerator", "Hits"]

# Rays start this far (relative to the scene size) off the surface, along the geometric
# normal, because embreex fixes tnear at 0: a ray starting on a surface hits it at t = 0.
RAY_EPSILON_SCALE = 2e-5
_NO_HIT = 1e37


def _embree() -> tuple[Any, Any, Any]:
    # Imported lazily: importing the tracer checks that embreex is installed, but only
    # building an accelerator loads it.
    from embreex import rtcore as rtc
    from embreex import rtcore_scene as rtcs
    from embreex.mesh_construction import TriangleMesh

    return rtc, rtcs, TriangleMesh


@dataclass
class Hits:
    """Nearest hits of a batch of rays (arrays over the rays of the batch)."""

    valid: np.ndarray        # bool, the ray hit something
    object_index: np.ndarray  # int64 scene object, -1 on a miss
    triangle: np.ndarray     # int64 index into the accelerator's global triangle tables
    u: np.ndarray            # float64 barycentrics: p = (1 - u - v) v0 + u v1 + v v2
    v: np.ndarray
    distance: np.ndarray     # float64 tfar


class Accelerator:
    """Embree scenes and per-triangle tables for one :class:`Scene`.

    Attributes
    ----------
    triangle_vertices, triangle_normals
        (T, 3, 3) object-space vertex positions and shading normals of every triangle.
    triangle_object
        (T,) object of each triangle.
    epsilon
        Ray origin offset along the geometric normal.
    """

    def __init__(self, scene: Scene) -> None:
        rtc, rtcs, triangle_mesh = _embree()
        self.scene = scene
        self.device = rtc.EmbreeDevice()
        vertices, normals, owners, self.triangle_offset = [], [], [], []
        offset = 0
        for i, obj in enumerate(scene.objects):
            vertices.append(obj.vertices[obj.faces])
            normals.append(obj.normals[obj.faces])
            owners.append(np.full(len(obj.faces), i, np.int64))
            self.triangle_offset.append(offset)
            offset += len(obj.faces)
        self.triangle_vertices = np.concatenate(vertices)
        self.triangle_normals = np.concatenate(normals)
        self.triangle_object = np.concatenate(owners)
        tv = self.triangle_vertices
        # Unit geometric normals, once per triangle rather than once per hit.
        self.triangle_geometric_normal = normalize(cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0]))
        self.triangle_offset = np.asarray(self.triangle_offset, np.int64)
        self.object_material = np.array([o.material for o in scene.objects], np.int64)
        self.object_emission = np.array([o.emission if o.emission is not None else np.zeros(3)
                                         for o in scene.objects])
        extent = np.ptp(self.triangle_vertices.reshape(-1, 3), axis=0).max()
        self.epsilon = RAY_EPSILON_SCALE * max(float(extent), 1.0)

        self.static_objects = [i for i, o in enumerate(scene.objects) if o.motion is None]
        self.moving_objects = [i for i, o in enumerate(scene.objects) if o.motion is not None]
        self.static_scene = None
        if self.static_objects:
            self.static_scene = rtcs.EmbreeScene(self.device)
            for i in self.static_objects:  # geomID = attach order
                obj = scene.objects[i]
                triangle_mesh(self.static_scene, obj.vertices.astype(np.float32), obj.faces.astype(np.int32))
        self.static_geometry_object = np.asarray(self.static_objects, np.int64)
        self.moving_scenes = []
        for i in self.moving_objects:
            s = rtcs.EmbreeScene(self.device)
            obj = scene.objects[i]
            triangle_mesh(s, obj.vertices.astype(np.float32), obj.faces.astype(np.int32))
            self.moving_scenes.append(s)
        self._lock = threading.Lock()
        self.record: list[tuple[str, int, np.ndarray, np.ndarray, np.ndarray | None]] | None = None
        self._commit()

    @property
    def scene_count(self) -> int:
        """Embree scenes every ray is traced against (static geometry plus each moving object)."""
        return int(self.static_scene is not None) + len(self.moving_scenes)

    def _commit(self) -> None:
        # The BVH is built lazily on the first run(); build it here, once, from one thread.
        probe_o = np.zeros((1, 3), np.float32)
        probe_d = np.array([[0.0, 0.0, 1.0]], np.float32)
        for s in ([self.static_scene] if self.static_scene is not None else []) + self.moving_scenes:
            s.run(probe_o, probe_d, output=1)

    def _log(self, query: str, scene_index: int, o: np.ndarray, d: np.ndarray, dist: np.ndarray | None) -> None:
        if self.record is not None:
            with self._lock:
                self.record.append((query, scene_index, o.copy(), d.copy(), None if dist is None else dist.copy()))

    def _object_space_rays(self, k: int, o: np.ndarray, d: np.ndarray,
                           time: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        motion = self.scene.objects[self.moving_objects[k]].motion
        rotation, translation = motion.world_from_object(time)
        # Inverse of a rigid map: x_object = R^T (x_world - T).
        o_obj = np.einsum("nji,nj->ni", rotation, o - translation)
        d_obj = np.einsum("nji,nj->ni", rotation, d)
        return o_obj, d_obj

    def intersect(self, o: np.ndarray, d: np.ndarray, time: np.ndarray) -> Hits:
        """Nearest hits of rays ``o + t d`` (unit ``d``) at times ``time``."""
        n = len(o)
        best = np.full(n, _NO_HIT)
        obj = np.full(n, -1, np.int64)
        tri = np.zeros(n, np.int64)
        u = np.zeros(n)
        v = np.zeros(n)
        if self.static_scene is not None:
            o32, d32 = o.astype(np.float32), d.astype(np.float32)
            self._log("INTERSECT", -1, o32, d32, None)
            r = self.static_scene.run(o32, d32, output=1)
            hit = r["geomID"] >= 0
            geom = r["geomID"][hit].astype(np.int64)
            obj[hit] = self.static_geometry_object[geom]
            tri[hit] = self.triangle_offset[obj[hit]] + r["primID"][hit]
            u[hit], v[hit] = r["u"][hit], r["v"][hit]
            best[hit] = r["tfar"][hit]
        for k, s in enumerate(self.moving_scenes):
            o_obj, d_obj = self._object_space_rays(k, o, d, time)
            o32, d32 = o_obj.astype(np.float32), d_obj.astype(np.float32)
            self._log("INTERSECT", k, o32, d32, None)
            r = s.run(o32, d32, output=1)
            closer = (r["geomID"] >= 0) & (r["tfar"] < best)
            index = self.moving_objects[k]
            obj[closer] = index
            tri[closer] = self.triangle_offset[index] + r["primID"][closer]
            u[closer], v[closer] = r["u"][closer], r["v"][closer]
            best[closer] = r["tfar"][closer]
        return Hits(obj >= 0, obj, tri, u, v, best)

    def occluded(self, o: np.ndarray, d: np.ndarray, distance: np.ndarray, time: np.ndarray) -> np.ndarray:
        """True where something blocks the segment ``o + t d``, ``0 <= t < distance``."""
        blocked = np.zeros(len(o), bool)
        dist32 = np.minimum(distance, 1e30).astype(np.float32)
        if self.static_scene is not None:
            o32, d32 = o.astype(np.float32), d.astype(np.float32)
            self._log("OCCLUDED", -1, o32, d32, dist32)
            # embreex overwrites the distance array in place, so it gets a copy.
            blocked |= self.static_scene.run(o32, d32, dists=dist32.copy(), query="OCCLUDED") == 0
        for k, s in enumerate(self.moving_scenes):
            o_obj, d_obj = self._object_space_rays(k, o, d, time)
            o32, d32 = o_obj.astype(np.float32), d_obj.astype(np.float32)
            self._log("OCCLUDED", k, o32, d32, dist32)
            blocked |= s.run(o32, d32, dists=dist32.copy(), query="OCCLUDED") == 0
        return blocked

    def surface(self, hits: Hits, time: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """World-space hit points, unit geometric and shading normals, and object-space points.

        Only for the rays where ``hits.valid``; arrays are over those rays.
        """
        tri = hits.triangle[hits.valid]
        u, v = hits.u[hits.valid], hits.v[hits.valid]
        w = 1.0 - u - v
        tv = self.triangle_vertices[tri]
        tn = self.triangle_normals[tri]
        p_object = w[:, None] * tv[:, 0] + u[:, None] * tv[:, 1] + v[:, None] * tv[:, 2]
        n_geometric = self.triangle_geometric_normal[tri]
        n_shading = normalize(w[:, None] * tn[:, 0] + u[:, None] * tn[:, 1] + v[:, None] * tn[:, 2])
        p = p_object.copy()
        frozen = [i for i, o in enumerate(self.scene.objects) if o.frozen_pose is not None]
        if frozen:
            obj = hits.object_index[hits.valid]
            for k in frozen:
                sel = obj == k
                rotation, translation = self.scene.objects[k].frozen_pose
                p_object[sel] = np.einsum("ni,ij->nj", p_object[sel] - translation, rotation)  # R^T (p - T)
        if self.moving_objects:
            obj = hits.object_index[hits.valid]
            t = time[hits.valid]
            for k in self.moving_objects:
                sel = obj == k
                if not sel.any():
                    continue
                rotation, translation = self.scene.objects[k].motion.world_from_object(t[sel])
                p[sel] = np.einsum("nij,nj->ni", rotation, p_object[sel]) + translation
                n_geometric[sel] = np.einsum("nij,nj->ni", rotation, n_geometric[sel])
                n_shading[sel] = np.einsum("nij,nj->ni", rotation, n_shading[sel])
        return p, n_geometric, n_shading, p_object
