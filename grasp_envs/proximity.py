"""Lower bounds on the distance between geoms, to skip contact-list reads that cannot find a counted contact.

A batched simulation's contact list has no batched binding: ``BatchVecEnv`` reads it one simulation at a time
(``mujoco.batch.Batch.get_data``). :class:`ContactScreen` decides from the geoms' poses alone, for all simulations at
once, which of them may hold a contact between a counted geom pair; the others' counts are zero and their lists are
not read. Each bound is at most the true distance, so a simulation is skipped only where no counted pair can touch.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

# a pair is screened out only when its lower bound exceeds this (m): far above the collision functions' tolerances
CLEARANCE = 1e-3
_TINY = 1e-12
# a group of screened pairs: its first geoms' columns among the screen's segment-like geoms (None: all, in order),
# its second geoms, that geom where they are one (None otherwise), and each pair's largest bound to touch
_Group = tuple[NDArray[np.int64] | None, NDArray[np.int64], int | None, Array]


def _dot(a: Array, b: Array) -> Array:
    return np.einsum("...i,...i->...", a, b)


def segment_segment_distance(p1: Array, q1: Array, p2: Array, q2: Array) -> Array:
    """Distance between segments ``p1 q1`` and ``p2 q2`` (``(..., 3)`` each), the closest-point method of Ericson's
    *Real-Time Collision Detection* (5.1.9), for segments of any length, parallel ones included."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    c, b = _dot(d1, r), _dot(d1, d2)
    a_safe, e_safe = np.maximum(a, _TINY), np.maximum(e, _TINY)
    denom = a * e - b * b
    s = np.where(denom > _TINY, np.clip((b * f - c * e) / np.where(denom > _TINY, denom, 1.0), 0.0, 1.0), 0.0)
    s = np.where(e > _TINY, s, np.clip(-c / a_safe, 0.0, 1.0))  # the second segment a point: its nearest point
    s = np.where(a > _TINY, s, 0.0)
    t = np.where(e > _TINY, (b * s + f) / e_safe, 0.0)
    below, above = t < 0.0, t > 1.0
    s = np.where(below, np.clip(-c / a_safe, 0.0, 1.0), np.where(above, np.clip((b - c) / a_safe, 0.0, 1.0), s))
    s = np.where(a > _TINY, s, 0.0)
    t = np.clip(t, 0.0, 1.0)
    gap = (p1 + d1 * s[..., None]) - (p2 + d2 * t[..., None])
    return np.sqrt(_dot(gap, gap))


def segment_box_separation(p: Array, q: Array, center: Array, rotation: Array, half_sizes: Array) -> Array:
    """A lower bound on the distance between segment ``p q`` and a box (``rotation`` ``(..., 3, 3)`` with the box's
    axes as columns, as MuJoCo's ``geom_xmat``): the largest gap along one of the box's axes."""
    local_p = np.einsum("...ji,...j->...i", rotation, p - center)
    local_q = np.einsum("...ji,...j->...i", rotation, q - center)
    low, high = np.minimum(local_p, local_q), np.maximum(local_p, local_q)
    gaps = np.maximum(np.maximum(low - half_sizes, -half_sizes - high), 0.0)
    return gaps.max(axis=-1)


def segment_plane_distance(p: Array, q: Array, point: Array, normal: Array) -> Array:
    """Signed height of the lower end of segment ``p q`` above a plane (negative: below it)."""
    return np.minimum(_dot(p - point, normal), _dot(q - point, normal))


def never_collide(model: mujoco.MjModel, geom1: int, geom2: int) -> bool:
    """Whether MuJoCo's collision filter always leaves out geoms ``geom1`` and ``geom2`` (a model without ``<pair>``
    elements): on one body, neither's ``contype`` matching the other's ``conaffinity``, or their bodies excluded."""
    body1, body2 = int(model.geom_bodyid[geom1]), int(model.geom_bodyid[geom2])
    if body1 == body2:
        return True
    contype, conaffinity = model.geom_contype, model.geom_conaffinity
    if not (contype[geom1] & conaffinity[geom2] or contype[geom2] & conaffinity[geom1]):
        return True
    low, high = min(body1, body2), max(body1, body2)
    return bool(np.isin((low << 16) + high, model.exclude_signature))


class ContactScreen:
    """Which simulations may hold a contact between any of ``pairs`` (geom id pairs), from ``geom_xpos`` and
    ``geom_xmat`` of the same collision pass.

    Capsules and spheres are segments with a radius (a sphere's has no length); other geoms but boxes and planes are
    the sphere that bounds them (MuJoCo's ``geom_rbound``). Against a plane a segment is bounded exactly, against a
    box by the largest gap along the box's axes. Pairs that MuJoCo's filter never collides count nothing and are left
    out (``never_collide``). A model with a pair of two boxes or planes among ``pairs``, or whose
    margins can be overridden (``<pair>`` elements, the override flag), screens nothing out.
    """

    def __init__(self, model: mujoco.MjModel, pairs: Sequence[tuple[int, int]]):
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        override = model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_OVERRIDE
        self.enabled = bool(len(self.pairs)) and model.npair == 0 and not override
        types = model.geom_type
        geom = mujoco.mjtGeom
        plane, box, capsule = int(geom.mjGEOM_PLANE), int(geom.mjGEOM_BOX), int(geom.mjGEOM_CAPSULE)
        segment_like = (capsule, int(geom.mjGEOM_SPHERE))
        self._half_length = np.where(types == capsule, model.geom_size[:, 1], 0.0)
        self._radius = np.where(np.isin(types, segment_like), model.geom_size[:, 0], model.geom_rbound)
        self._box_half = model.geom_size.copy()
        margins = np.maximum(model.geom_margin[self.pairs[:, 0]], model.geom_margin[self.pairs[:, 1]])
        # each pair as (segment, plane | box | segment); a pair of two planes or boxes is never screened out
        rows: dict[str, list[tuple[int, int, float]]] = {"plane": [], "box": [], "segment": []}
        for (g1, g2), margin in zip(self.pairs.tolist(), margins.tolist(), strict=True):
            if never_collide(model, g1, g2):
                continue
            if types[g1] in (plane, box):
                g1, g2 = g2, g1
            if types[g1] in (plane, box):
                self.enabled = False
                continue
            rows["plane" if types[g2] == plane else "box" if types[g2] == box else "segment"].append((g1, g2, margin))
        # the segment-like geoms of every group, whose end points are computed once per call
        self._firsts = np.unique([first for group in rows.values() for first, _, _ in group]).astype(np.int64)
        # per group (_Group), the largest bound at which a pair may touch: the first's radius, the margin and CLEARANCE
        self._groups: dict[str, _Group] = {}
        for kind, group in rows.items():
            if group:
                first, second, margin = (np.array(values) for values in zip(*group, strict=True))
                columns = np.searchsorted(self._firsts, first)
                same = len(first) == len(self._firsts) and bool((columns == np.arange(len(first))).all())
                reach = self._radius[first] + margin.astype(np.float64) + CLEARANCE
                second = second.astype(np.int64)
                shared = int(second[0]) if bool((second == second[0]).all()) else None
                self._groups[kind] = (None if same else columns, second, shared, reach)

    def _segments(self, geoms: NDArray[np.int64], xpos: Array, frames: Array) -> tuple[Array, Array]:
        """Centres and half axes of each geom's segment (a capsule's axis along its z; zero for other geoms)."""
        return xpos[:, geoms], frames[:, geoms][..., 2] * self._half_length[geoms, None]

    def may_touch(self, geom_xpos: Array, geom_xmat: Array) -> NDArray[np.bool_]:
        """``(n,)``: whether a simulation may hold a contact between a screened pair (``geom_xpos`` ``(n, ngeom, 3)``,
        ``geom_xmat`` ``(n, ngeom, 9)``)."""
        n = len(geom_xpos)
        if not self.enabled:
            return np.ones(n, dtype=bool)
        possible = np.zeros(n, dtype=bool)
        frames = geom_xmat.reshape(n, -1, 3, 3)
        segments = self._segments(self._firsts, geom_xpos, frames)
        for kind, (rows, second, shared, reach) in self._groups.items():
            center, axis = segments if rows is None else (segments[0][:, rows], segments[1][:, rows])
            if shared is not None and kind == "plane":  # the lower end's height: the centre's less the half axis'
                normal = frames[:, shared, :, 2, None]
                bound = ((center - geom_xpos[:, shared, None]) @ normal)[..., 0] - np.abs(axis @ normal)[..., 0]
            elif shared is not None and kind == "box":  # in the box's frame, the largest gap along one of its axes
                rotation = frames[:, shared]
                local, extent = (center - geom_xpos[:, shared, None]) @ rotation, np.abs(axis @ rotation)
                # (not clipped at 0 as segment_box_separation's: it is compared with a positive reach only)
                bound = (np.abs(local) - extent - self._box_half[shared]).max(axis=-1)
            elif kind == "plane":
                normal = frames[:, second][..., 2]
                bound = segment_plane_distance(center - axis, center + axis, geom_xpos[:, second], normal)
            elif kind == "box":
                bound = segment_box_separation(
                    center - axis, center + axis, geom_xpos[:, second], frames[:, second], self._box_half[second]
                )
            else:
                center2, axis2 = self._segments(second, geom_xpos, frames)
                distance = segment_segment_distance(center - axis, center + axis, center2 - axis2, center2 + axis2)
                bound = distance - self._radius[second]
            possible |= (bound <= reach).any(axis=1)
        return possible
