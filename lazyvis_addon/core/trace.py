"""Ray casting against a triangle soup: Embree (through embreex) and a brute-force numpy oracle.

Both tracers share one contract, so the numpy one can cross-check Embree in tests and stand in for tiny
scenes:

* A ray is ``origin + t * direction`` for ``0 <= t <= tfar``. Directions need not be unit length: ``t`` is
  parametric along the direction *as given* (Embree's convention, kept here), so the distance travelled is
  ``t * |direction|`` and ``tfar`` is in the same units as ``t``. A zero direction never hits.
* ``tnear`` is fixed at 0 (embreex offers no way to set it): callers that start rays on a surface offset
  the origins themselves. A hit exactly at ``t = 0`` counts.
* Triangles are two-sided (no back-face culling); degenerate (zero-area) triangles are never hit.
* A ray whose ``tfar`` is negative or NaN is not traced: it misses and is not occluded.
* Barycentrics: the hit point is ``(1 - u - v) * v0 + u * v1 + v * v2`` for the triangle's vertices.
* Work is split into batches of rays run on a small thread pool; embreex releases the GIL while tracing,
  so threads give a real speed-up.

Embree works in float32: triangles, origins, directions and ``tfar`` are rounded to float32 at the call
(``tfar`` downwards, so Embree never reports a hit beyond the float64 ``tfar``); everything else is float64.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass

import numpy as np

from .parallel import map_batches

DEFAULT_BATCH_SIZE = 262144  # rays per batch handed to one worker thread
MAX_DEFAULT_THREADS = 8
_MIN_BATCH_SIZE = 4096  # never split work into batches smaller than this just to feed threads
_MAX_RAY_TRIANGLE_PAIRS = 1 << 21  # numpy tracer: rays x triangles per chunk (a few 16 MB float64 arrays)


@dataclass
class Hits:
    """Nearest hit of each ray.

    Attributes
    ----------
    index_triangle : (N,) int64
        Index of the hit triangle into the tracer's ``triangles``, -1 on a miss.
    t : (N,) float64
        Ray parameter of the hit, in units of the ray's ``|direction|`` (the distance travelled is
        ``t * |direction|``); ``np.inf`` on a miss.
    u, v : (N,) float64
        Barycentrics of the hit: point = ``(1 - u - v) * v0 + u * v1 + v * v2``; 0 on a miss.
    """

    index_triangle: np.ndarray
    t: np.ndarray
    u: np.ndarray
    v: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(N,) bool: the ray hit a triangle."""
        return self.index_triangle >= 0

    def __len__(self) -> int:
        return len(self.index_triangle)

    @classmethod
    def misses(cls, count: int) -> "Hits":
        """``count`` rays that hit nothing."""
        return cls(np.full(count, -1, dtype=np.int64), np.full(count, np.inf), np.zeros(count), np.zeros(count))


def default_thread_count() -> int:
    """Worker threads used when none are given: the CPU count, capped at ``MAX_DEFAULT_THREADS``."""
    return max(1, min(os.cpu_count() or 1, MAX_DEFAULT_THREADS))


class _TracerBase:
    """Input checking, empty-scene and inactive-ray handling, batching, threads and the ray counter.

    Subclasses implement ``_intersect_batch`` and ``_occluded_batch`` for rays that are all active
    (``tfar >= 0``) against a scene with at least one triangle.
    """

    def __init__(self, triangles, threads: int | None, batch_size: int, default_threads: int) -> None:
        triangles = np.asarray(triangles, dtype=np.float64)
        if triangles.ndim != 3 or triangles.shape[1:] != (3, 3):
            raise ValueError(f"triangles must have shape T x 3 x 3, got {triangles.shape}")
        if not np.isfinite(triangles).all():
            raise ValueError("triangles contain NaN or infinite vertex coordinates")
        threads = default_threads if threads is None else int(threads)
        if threads < 1:
            raise ValueError(f"threads must be at least 1, not {threads}")
        if int(batch_size) < 1:
            raise ValueError(f"batch_size must be at least 1, not {batch_size}")
        self.triangles = triangles
        self.threads = threads
        self.batch_size = int(batch_size)
        self.n_rays_cast = 0  # rays passed to intersect / occluded so far (benchmark counter)
        self._counter_lock = threading.Lock()

    @property
    def triangle_count(self) -> int:
        return len(self.triangles)

    # -- public API ---------------------------------------------------------------------------------------
    def intersect(self, origins, directions, tfar=None) -> Hits:
        """Nearest hit of each ray ``origins + t * directions`` with ``0 <= t <= tfar``.

        Parameters
        ----------
        origins, directions : (N, 3) float64
            Ray origins (world units) and directions (any non-zero length; ``t`` is in units of it).
        tfar : (N,) float64, scalar or None
            Largest accepted ``t`` per ray; None means unbounded. Negative or NaN: the ray misses.

        Returns
        -------
        Hits
            ``index_triangle`` (N,) int64, ``t``, ``u``, ``v`` (N,) float64.
        """
        origins, directions, tfar = self._check_rays(origins, directions, tfar)
        hits = Hits.misses(len(origins))

        def run(index_ray: np.ndarray | slice) -> None:
            index_triangle, t, u, v = self._intersect_batch(origins[index_ray], directions[index_ray], tfar[index_ray])
            hits.index_triangle[index_ray], hits.t[index_ray], hits.u[index_ray], hits.v[index_ray] = \
                index_triangle, t, u, v

        self._trace(tfar, run)
        return hits

    def nearest_float32(self, origins: np.ndarray, directions: np.ndarray, tfar: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
        """``intersect`` for rays already in Embree's float32 (``origins``, ``directions`` (N, 3) float32,
        ``tfar`` (N,) float32, rounded down as ``intersect`` rounds it, all >= 0), for callers that gather
        them in a compiled loop: the hit triangle (N,) int64 (-1 on a miss) and the hit ``t`` (N,) float64
        (any value on a miss), no barycentrics. The results are ``intersect``'s for the same float32 rays.
        """
        hits = self.intersect(origins.astype(np.float64), directions.astype(np.float64), tfar.astype(np.float64))
        return hits.index_triangle, hits.t

    def occluded(self, origins, directions, tfar=None) -> np.ndarray:
        """Whether anything lies on each ray ``origins + t * directions`` for ``0 <= t <= tfar``.

        Parameters
        ----------
        origins, directions : (N, 3) float64
            Ray origins (world units) and directions (any non-zero length; ``t`` is in units of it).
        tfar : (N,) float64, scalar or None
            Largest ``t`` that occludes, per ray (for a shadow ray to a point at ``origin + direction``,
            slightly less than 1); None means unbounded. Negative or NaN: never occluded.

        Returns
        -------
        (N,) bool
        """
        origins, directions, tfar = self._check_rays(origins, directions, tfar)
        occluded = np.zeros(len(origins), dtype=bool)

        def run(index_ray: np.ndarray | slice) -> None:
            occluded[index_ray] = self._occluded_batch(origins[index_ray], directions[index_ray], tfar[index_ray])

        self._trace(tfar, run)
        return occluded

    def close(self) -> None:
        """Nothing to release: the batches run on the process's shared pool (``parallel.map_batches``). Kept
        for the context manager and callers that close a tracer."""

    def __enter__(self):
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    # -- backend hooks ------------------------------------------------------------------------------------
    def _intersect_batch(self, origins: np.ndarray, directions: np.ndarray, tfar: np.ndarray):
        """(index_triangle int64, t, u, v float64), each (n,), for active rays; misses as in ``Hits``."""
        raise NotImplementedError

    def _occluded_batch(self, origins: np.ndarray, directions: np.ndarray, tfar: np.ndarray) -> np.ndarray:
        """(n,) bool for active rays."""
        raise NotImplementedError

    # -- helpers ------------------------------------------------------------------------------------------
    @staticmethod
    def _check_rays(origins, directions, tfar):
        origins = np.asarray(origins)
        directions = np.asarray(directions)
        if origins.ndim != 2 or origins.shape[1] != 3:
            raise ValueError(f"ray origins must have shape N x 3, got {origins.shape}")
        if directions.shape != origins.shape:
            raise ValueError(f"ray directions must have the shape of the origins {origins.shape}, "
                             f"got {directions.shape}")
        count = len(origins)
        if tfar is None:
            tfar = np.full(count, np.inf)
        else:
            tfar = np.asarray(tfar, dtype=np.float64)
            if tfar.ndim == 0:
                tfar = np.full(count, float(tfar))
            elif tfar.shape != (count,):
                raise ValueError(f"tfar must be a scalar or have shape ({count},), got {tfar.shape}")
        return origins, directions, tfar

    def _trace(self, tfar: np.ndarray, run) -> None:
        """Call ``run(index_ray)`` over batches of the rays worth tracing, on the thread pool when it pays.

        ``index_ray`` is a slice or an int64 index array into the N rays. Nothing is traced in an empty
        scene, nor rays whose ``tfar`` is negative or NaN (their results stay a miss / not occluded).
        """
        count = len(tfar)
        if self.triangle_count and count:
            active = tfar >= 0  # False for NaN
            index_active = None if active.all() else np.flatnonzero(active)
            count_active = count if index_active is None else len(index_active)
            per_thread = -(-count_active // self.threads)
            size = max(1, min(self.batch_size, max(per_thread, _MIN_BATCH_SIZE)))
            batches = [slice(start, min(start + size, count_active)) for start in range(0, count_active, size)]
            if index_active is not None:
                batches = [index_active[batch] for batch in batches]
            if self.threads == 1 or len(batches) <= 1:
                for batch in batches:
                    run(batch)
            else:
                map_batches(run, batches, self.threads)  # the shared pool; re-raises a batch's exception
        with self._counter_lock:
            self.n_rays_cast += count


def _float32_not_above(values: np.ndarray) -> np.ndarray:
    """float64 -> float32 rounding toward -inf (so a float32 ``tfar`` never exceeds the float64 one)."""
    with np.errstate(over="ignore"):
        rounded = values.astype(np.float32)
    above = rounded > values
    if above.any():
        rounded[above] = np.nextafter(rounded[above], np.float32(-np.inf))
    return rounded


class RayTracer(_TracerBase):
    """Embree ray tracer over a static triangle soup (the float32 boundary of the core lives here).

    Parameters
    ----------
    triangles : (T, 3, 3) float64
        Triangle vertices in world units; T may be 0 (every ray misses, Embree is not used).
    threads : int or None
        Worker threads for batches; default ``min(os.cpu_count(), 8)``.
    batch_size : int
        Rays per batch (per Embree call).

    Attributes
    ----------
    n_rays_cast : int
        Rays passed to ``intersect`` / ``occluded`` so far.
    """

    def __init__(self, triangles, threads: int | None = None, batch_size: int = DEFAULT_BATCH_SIZE) -> None:
        super().__init__(triangles, threads, batch_size, default_thread_count())
        self._embree_scene = None
        self._embree_mesh = None
        if self.triangle_count:
            import embreex.mesh_construction as embree_mesh
            import embreex.rtcore_scene as embree_scene

            with np.errstate(over="ignore"):  # an overflow is reported just below, as a ValueError
                triangles_f32 = np.ascontiguousarray(self.triangles, dtype=np.float32)
            if not np.isfinite(triangles_f32).all():
                raise ValueError("triangle coordinates overflow float32")
            self._embree_scene = embree_scene.EmbreeScene()
            self._embree_mesh = embree_mesh.TriangleMesh(self._embree_scene, triangles_f32)
            self._triangles_f32 = triangles_f32  # keep the buffer alive as long as the scene
            # embreex commits the scene lazily on the first run(); do it now, before threads share it.
            self._embree_scene.run(np.zeros((1, 3), np.float32), np.array([[0.0, 0.0, 1.0]], np.float32))

    def _intersect_batch(self, origins, directions, tfar):
        # embreex writes the hit t into the dists buffer it is given: always hand it a fresh array.
        result = self._embree_scene.run(np.ascontiguousarray(origins, dtype=np.float32),
                                        np.ascontiguousarray(directions, dtype=np.float32),
                                        dists=_float32_not_above(tfar), output=1)
        index_triangle = result["primID"].astype(np.int64)  # -1 on a miss
        hit = index_triangle >= 0
        t = np.where(hit, result["tfar"].astype(np.float64), np.inf)
        u = np.where(hit, result["u"].astype(np.float64), 0.0)
        v = np.where(hit, result["v"].astype(np.float64), 0.0)
        return index_triangle, t, u, v

    def nearest_float32(self, origins, directions, tfar):
        index_triangle = np.full(len(origins), -1, np.int64)
        t = np.empty(len(origins))

        def run(index_ray: np.ndarray | slice) -> None:
            # A copy of tfar: embreex writes the hits' t into the buffer it is given.
            result = self._embree_scene.run(origins[index_ray], directions[index_ray], dists=tfar[index_ray].copy(),
                                            output=1)
            index_triangle[index_ray] = result["primID"]
            t[index_ray] = result["tfar"]

        self._trace(tfar, run)
        return index_triangle, t

    def _occluded_batch(self, origins, directions, tfar):
        # OCCLUDED returns int32 per ray: 0 when occluded (Embree set the ray's tfar to -inf), -1 when not.
        # A negative input tfar would also read as 0: such rays never get here (see _trace).
        result = self._embree_scene.run(np.ascontiguousarray(origins, dtype=np.float32),
                                        np.ascontiguousarray(directions, dtype=np.float32),
                                        dists=_float32_not_above(tfar), query="OCCLUDED")
        return result == 0


class NumpyRayTracer(_TracerBase):
    """Brute-force Möller–Trumbore in float64 numpy: every ray against every triangle, chunked.

    Same API, attributes and conventions as ``RayTracer``; meant to cross-check it and for tiny scenes.
    Each chunk holds at most ``2**21`` ray-triangle pairs (a few 16 MB float64 arrays).

    Parameters
    ----------
    triangles : (T, 3, 3) float64
    threads : int or None
        Worker threads for batches; default 1 (numpy's matrix products are already multi-threaded).
    batch_size : int
        Rays per batch.
    """

    def __init__(self, triangles, threads: int | None = None, batch_size: int = DEFAULT_BATCH_SIZE) -> None:
        super().__init__(triangles, threads, batch_size, 1)
        # The per-pair Möller–Trumbore quantities are rewritten with triple-product identities so that
        # every (rays x triangles) term is one matrix product of per-ray and per-triangle vectors.
        v0, v1, v2 = self.triangles[:, 0], self.triangles[:, 1], self.triangles[:, 2]
        self._edge1 = v1 - v0  # (T, 3)
        self._edge2 = v2 - v0
        self._normal = np.cross(self._edge1, self._edge2)  # unnormalised, (T, 3)
        self._normal_length = np.linalg.norm(self._normal, axis=1)
        self._edge2_cross_v0 = np.cross(self._edge2, v0)
        self._edge1_cross_v0 = np.cross(self._edge1, v0)
        self._v0_dot_normal = np.einsum("ij,ij->i", v0, self._normal)

    def _candidates(self, origins, directions, tfar):
        """Per ray-triangle pair of a chunk: accepted hit mask and t, u, v, each (n, T)."""
        origins = np.asarray(origins, dtype=np.float64)
        directions = np.asarray(directions, dtype=np.float64)
        origin_cross_direction = np.cross(origins, directions)  # (n, 3)
        # det = edge1 . (d x edge2) = -d . normal
        det = -(directions @ self._normal.T)
        not_parallel = np.abs(det) > 1e-12 * np.linalg.norm(directions, axis=1)[:, None] * self._normal_length
        inv_det = np.zeros_like(det)  # 0 for (near-)parallel pairs, which are rejected anyway
        np.divide(1.0, det, out=inv_det, where=not_parallel)
        # u = (o - v0) . (d x edge2) / det = (edge2 . (o x d) - d . (edge2 x v0)) / det
        u = origin_cross_direction @ self._edge2.T
        u -= directions @ self._edge2_cross_v0.T
        u *= inv_det
        # v = d . ((o - v0) x edge1) / det = (d . (edge1 x v0) - edge1 . (o x d)) / det
        v = directions @ self._edge1_cross_v0.T
        v -= origin_cross_direction @ self._edge1.T
        v *= inv_det
        # t = edge2 . ((o - v0) x edge1) / det = ((o - v0) . normal) / det
        t = origins @ self._normal.T
        t -= self._v0_dot_normal
        t *= inv_det
        accepted = not_parallel & (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0) & (t >= 0.0) & (t <= tfar[:, None])
        return accepted, t, u, v

    def _chunks(self, count: int):
        size = max(1, _MAX_RAY_TRIANGLE_PAIRS // self.triangle_count)
        return [slice(start, min(start + size, count)) for start in range(0, count, size)]

    def _intersect_batch(self, origins, directions, tfar):
        count = len(origins)
        index_triangle = np.full(count, -1, dtype=np.int64)
        t_hit, u_hit, v_hit = np.full(count, np.inf), np.zeros(count), np.zeros(count)
        for chunk in self._chunks(count):
            accepted, t, u, v = self._candidates(origins[chunk], directions[chunk], tfar[chunk])
            t_accepted = np.where(accepted, t, np.inf)
            index_nearest = np.argmin(t_accepted, axis=1)
            index_ray = np.arange(len(index_nearest))
            t_nearest = t_accepted[index_ray, index_nearest]
            hit = np.isfinite(t_nearest)
            index_triangle[chunk] = np.where(hit, index_nearest, -1)
            t_hit[chunk] = t_nearest
            u_hit[chunk] = np.where(hit, u[index_ray, index_nearest], 0.0)
            v_hit[chunk] = np.where(hit, v[index_ray, index_nearest], 0.0)
        return index_triangle, t_hit, u_hit, v_hit

    def _occluded_batch(self, origins, directions, tfar):
        occluded = np.zeros(len(origins), dtype=bool)
        for chunk in self._chunks(len(origins)):
            accepted, _, _, _ = self._candidates(origins[chunk], directions[chunk], tfar[chunk])
            occluded[chunk] = accepted.any(axis=1)
        return occluded
