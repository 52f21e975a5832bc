"""GraspIt-style grasp qualities from contacts: epsilon (Ferrari-Canny, L1) and wrench-space volume.

Each contact's Coulomb friction cone is approximated by ``n_edges`` edges, each a force of unit
normal component plus a tangential part of length ``mu`` (GraspIt's convention). The wrench of an
edge force f applied at p is (f, (p - com) x f / max_radius), where ``max_radius`` is the largest
distance from the object's centre of mass to its surface: dividing the torque by it gives torques
the units of force, so the 6-D wrench space is unit-consistent and independent of object scale.
The grasp wrench space is the convex hull of all edge wrenches (the union, i.e. the L1 space);
epsilon is the distance from the origin to its boundary, volume its 6-D volume.

Positions and normals may be in any frame (usually the world frame) as long as ``com`` is in the
same one. Lengths are metres; epsilon and volume are dimensionless for unit forces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import ConvexHull, QhullError

FRICTION = 1.0  # the Barrett's rubber on common materials (GraspIt's value)
CONE_EDGES = 8


@dataclass(frozen=True)
class GraspQuality:
    """Qualities of one grasp.

    ``epsilon``: distance from the origin to the boundary of the grasp wrench space when the origin
    is inside (force closure); otherwise <= 0 (minus how far the origin lies beyond the nearest
    hull facet plane), and exactly 0 for a degenerate (lower-dimensional) wrench set.
    ``volume``: the hull's 6-D volume (0 when degenerate).
    """

    epsilon: float
    volume: float

    @property
    def force_closure(self) -> bool:
        return self.epsilon > 0.0


def max_radius(vertices: np.ndarray, com: np.ndarray) -> float:
    """Largest distance (m) from ``com`` to any of ``vertices`` (N x 3, same frame)."""
    return float(np.max(np.linalg.norm(np.asarray(vertices, float) - np.asarray(com, float), axis=1)))


def _tangents(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane orthogonal to unit ``n``."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1)
    return t1, np.cross(n, t1)


def friction_cone(force_direction: np.ndarray, mu: float = FRICTION, n_edges: int = CONE_EDGES) -> np.ndarray:
    """Edge forces (n_edges x 3) of the linearised friction cone about unit ``force_direction``.

    Each edge has a normal component of 1 and a tangential component of length ``mu``.
    """
    n = np.asarray(force_direction, float)
    n = n / np.linalg.norm(n)
    t1, t2 = _tangents(n)
    angles = 2.0 * np.pi * np.arange(n_edges) / n_edges
    return n[None, :] + mu * (np.cos(angles)[:, None] * t1[None, :] + np.sin(angles)[:, None] * t2[None, :])


def contact_wrenches(
    points: npt.ArrayLike,
    normals: npt.ArrayLike,
    com: npt.ArrayLike,
    radius: float,
    mu: float = FRICTION,
    n_edges: int = CONE_EDGES,
) -> np.ndarray:
    """All friction-cone edge wrenches ((N * n_edges) x 6) of N contacts.

    ``points``: contact positions on the object (N x 3). ``normals``: the object's outward surface
    normals there (N x 3): a finger pushes along ``-normal``. ``com``: the object's centre of mass,
    ``radius``: :func:`max_radius` of the object (m).
    """
    points = np.asarray(points, float).reshape(-1, 3)
    normals = np.asarray(normals, float).reshape(-1, 3)
    wrenches = []
    for p, n in zip(points, normals):
        forces = friction_cone(-n, mu, n_edges)
        torques = np.cross(p - np.asarray(com, float), forces) / radius
        wrenches.append(np.hstack([forces, torques]))
    return np.vstack(wrenches) if wrenches else np.zeros((0, 6))


def wrench_space_quality(wrenches: np.ndarray) -> GraspQuality:
    """Epsilon and volume of the convex hull of ``wrenches`` (M x 6)."""
    wrenches = np.asarray(wrenches, float)
    # Qhull needs a full-dimensional point set; fewer than 7 points or a rank-deficient set (e.g.
    # one contact) cannot enclose the origin, so they are degenerate by definition.
    if len(wrenches) < 7 or np.linalg.matrix_rank(wrenches, tol=1e-9) < 6:
        return GraspQuality(0.0, 0.0)
    try:
        hull = ConvexHull(wrenches)
    except QhullError:
        return GraspQuality(0.0, 0.0)
    # Facet equations are (unit normal, offset) with normal . x + offset <= 0 inside, so -offset is
    # the origin's signed distance to each facet plane: all positive iff the origin is inside.
    return GraspQuality(float(np.min(-hull.equations[:, -1])), float(hull.volume))


def grasp_quality(
    points: npt.ArrayLike,
    normals: npt.ArrayLike,
    com: npt.ArrayLike,
    radius: float,
    mu: float = FRICTION,
    n_edges: int = CONE_EDGES,
) -> GraspQuality:
    """Epsilon and volume of a grasp from its contacts (see :func:`contact_wrenches` for arguments)."""
    return wrench_space_quality(contact_wrenches(points, normals, com, radius, mu, n_edges))
