"""The hand, precomputed for the cheap stage of planning (:mod:`shapeviewer.grasp.search`).

Points and normals on the hand's collision geometry in the palm frame (origin at the centre of
the palm face, +z the approach; see :mod:`shapeviewer.grasp.hands`), over a grid of preshapes and
the closing range, so that evaluating a candidate grasp is a matter of moving arrays. Units:
metres and radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from shapeviewer.geometry import concatenate_meshes, o3d_tensor, raycasting_scene
from shapeviewer.grasp.hands import Hand, get_hand

APPROACH_SPACING = 0.005  # m between the lines of the approach rays (about the margin: nothing slips through)
CLOSE_SPACING = 0.01  # m between hand surface samples for closing and the table (most of the evaluation cost)
PRESHAPE_STEP = math.radians(7.5)  # grid of the Barrett spread in the cheap stage
CLOSE_STEPS = 15  # closing fractions 0..1 at which finger samples are precomputed (10 deg for the Barrett)


def _batch_link_poses(hand: Hand, joints: np.ndarray) -> dict[str, np.ndarray]:
    """``T_palm_link`` (B x 4 x 4) of every link for a batch of joint vectors (B x J).

    The same forward kinematics as :meth:`Hand.link_poses`, vectorised over the batch: the
    precomputation needs thousands of configurations.
    """
    joints = np.atleast_2d(np.asarray(joints, float))
    values = dict(zip(hand.joint_names, joints.T))
    b = len(joints)
    poses = {hand.model.root: np.broadcast_to(np.eye(4), (b, 4, 4))}
    for j in hand.model.joints:
        q = values.get(j.name, np.zeros(b))
        motion = np.broadcast_to(np.eye(4), (b, 4, 4)).copy()
        if j.kind in ("revolute", "continuous"):
            motion[:, :3, :3] = Rotation.from_rotvec(q[:, None] * j.axis[None, :]).as_matrix()
        elif j.kind == "prismatic":
            motion[:, :3, 3] = q[:, None] * j.axis[None, :]
        poses[j.child] = poses[j.parent] @ j.T_parent_joint @ motion
    return poses


def _surface_samples(hand: Hand, link: str, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points and outward normals (link frame) about ``spacing`` apart on a link's collision
    geometry, corners included (a box's corners are what first touches at a slant)."""
    pts, nrm = [], []
    for g in hand.model.collisions.get(link, ()):
        mesh = g.mesh()
        # Poisson-disc-like: oversample, then thin to the spacing (trimesh's sample_surface_even
        # does the same but warns whenever it keeps fewer points than asked for).
        count = max(int(math.ceil(mesh.area / spacing**2)), 1)
        sampled, faces = trimesh.sample.sample_surface(mesh, 3 * count, seed=0)
        sampled, keep = trimesh.points.remove_close(sampled, 0.7 * spacing)
        local = np.vstack([sampled, mesh.vertices])
        normals = np.vstack([mesh.face_normals[faces[keep]], mesh.vertex_normals])
        pts.append(local @ g.T_link_geom[:3, :3].T + g.T_link_geom[:3, 3])
        nrm.append(normals @ g.T_link_geom[:3, :3].T)
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.vstack(pts), np.vstack(nrm)


def _front_points(hand: Hand, poses: dict[str, np.ndarray]) -> np.ndarray:
    """The front-most point of the hand's collision geometry (palm frame) on each line parallel
    to the approach (+z) through a grid of step APPROACH_SPACING.

    When the hand translates along the approach, whatever it meets first lies ahead of one of
    these points, so rays cast from them find the first contact; points behind them on the same
    line could only hit later.
    """
    parts = []
    for link, T in poses.items():
        for g in hand.model.collisions.get(link, ()):
            parts.append(g.mesh().apply_transform(T @ g.T_link_geom))
    mesh = concatenate_meshes(parts)
    scene = raycasting_scene(mesh)
    (x0, y0, _), (x1, y1, z1) = mesh.bounds
    xs = np.arange(x0, x1 + APPROACH_SPACING, APPROACH_SPACING)
    ys = np.arange(y0, y1 + APPROACH_SPACING, APPROACH_SPACING)
    xy = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
    origins = np.hstack([xy, np.full((len(xy), 1), z1 + 0.01)])
    rays = np.hstack([origins, np.tile([0.0, 0.0, -1.0], (len(xy), 1))]).astype(np.float32)
    t = scene.cast_rays(o3d_tensor(rays))["t_hit"].numpy()
    hit = np.isfinite(t)
    return origins[hit] - t[hit, None] * [0.0, 0.0, 1.0]


def _pad(arrays: list[np.ndarray]) -> np.ndarray:
    """Stack point sets of different sizes, repeating each set's first point (harmless for minima)."""
    n = max(len(a) for a in arrays)
    return np.stack([np.vstack([a, np.repeat(a[:1], n - len(a), axis=0)]) for a in arrays])


@dataclass(frozen=True, eq=False)
class HandSamples:
    """Palm-frame samples of a hand over its preshapes and closing range.

    ``preshapes``: (S x D) open dof vectors (the Barrett's spread on a grid). ``approach_pts``:
    (S x P x 3) front-most open-hand points on a grid of lines along the approach (see
    :func:`_front_points`). ``body_pts``: (S x B x 3) all open-hand samples (for the table).
    ``close_pts``: (S x F x U x Q x 3) each finger's surface points that face its closing motion,
    at U closing fractions evenly spaced from open (0) to closed (1). ``vc_pos``/``vc_nrm``:
    (S x U x V x 3) virtual contacts with every finger at each fraction; ``vc_finger``: (V,) the
    finger moving each virtual contact (-1: the palm). ``n_init``: random candidates start from
    the first n_init preshapes (a Barrett spread up to 90 deg: beyond it fingers 1 and 2 fold
    back towards finger 3; annealing may still go there).
    """

    preshapes: np.ndarray
    approach_pts: np.ndarray
    body_pts: np.ndarray
    close_pts: np.ndarray
    vc_pos: np.ndarray
    vc_nrm: np.ndarray
    vc_finger: np.ndarray
    n_init: int


@cache
def hand_samples(name: str) -> HandSamples:
    """The samples of the hand called ``name`` (cached: computed once per process)."""
    hand = get_hand(name)
    pre = np.flatnonzero(~hand.closing_dofs).tolist()
    if len(pre) > 1:
        raise NotImplementedError("the cheap stage grids at most one preshape dof")
    open_dofs = np.array(hand.dof_open, float)
    closed_dofs = np.array(hand.dof_closed, float)
    if pre:
        i = pre[0]
        grid = np.arange(hand.dof_lower[i], hand.dof_upper[i] + 1e-9, PRESHAPE_STEP)
        preshapes = np.repeat(open_dofs[None], len(grid), axis=0)
        preshapes[:, i] = grid
        n_init = int(np.searchsorted(grid, math.pi / 2 + 1e-9))
    else:
        preshapes = open_dofs[None].copy()
        n_init = 1
    us = np.linspace(0.0, 1.0, CLOSE_STEPS)
    n_s, n_u = len(preshapes), len(us)
    dofs = preshapes[:, None, :] + us[None, :, None] * (closed_dofs - open_dofs)[None, None, :]
    joints = np.array([hand.joints_from_dofs(d) for d in dofs.reshape(-1, dofs.shape[-1])])
    poses = {k: v.reshape(n_s, n_u, 4, 4) for k, v in _batch_link_poses(hand, joints).items()}

    links = list(hand.model.collisions)
    samples = {link: _surface_samples(hand, link, CLOSE_SPACING) for link in links}

    def transform(link: str, s: int, k: int) -> tuple[np.ndarray, np.ndarray]:
        T = poses[link][s, k]
        pts, nrm = samples[link]
        return pts @ T[:3, :3].T + T[:3, 3], nrm @ T[:3, :3].T

    approach_pts, body_pts, close_pts = [], [], []
    for s in range(n_s):
        approach_pts.append(_front_points(hand, {link: poses[link][s, 0] for link in links}))
        body_pts.append(np.vstack([transform(link, s, 0)[0] for link in links]))
        per_finger = []
        for f in hand.fingers:
            per_u = []
            for k in range(n_u):
                # A point can touch first only where the surface faces its motion.
                k2 = k + 1 if k + 1 < n_u else k - 1
                pts, nrm = (np.vstack(a) for a in zip(*(transform(link, s, k) for link in f.links)))
                nxt = np.vstack([transform(link, s, k2)[0] for link in f.links])
                v = (nxt - pts) * (1 if k2 > k else -1)
                keep = np.einsum("ij,ij->i", nrm, v) > 0.1 * np.linalg.norm(v, axis=1)
                per_u.append(pts[keep] if keep.any() else pts)
            per_finger.append(per_u)
        close_pts.append(per_finger)
    flat = [a for per_finger in close_pts for per_u in per_finger for a in per_u]
    close = _pad(flat).reshape(n_s, len(hand.fingers), n_u, -1, 3)

    finger_of = {link: i for i, f in enumerate(hand.fingers) for link in f.links}
    vc_finger = np.array([finger_of.get(v.link, -1) for v in hand.virtual_contacts])
    vc_p = np.stack([poses[v.link] @ np.append(v.point, 1.0) for v in hand.virtual_contacts], axis=2)[..., :3]
    vc_n = np.stack([poses[v.link][..., :3, :3] @ np.asarray(v.normal, float) for v in hand.virtual_contacts], axis=2)
    # float32 halves the memory traffic of the vectorised evaluation, which is what it costs.
    f32 = np.float32
    return HandSamples(
        preshapes,
        _pad(approach_pts).astype(f32),
        _pad(body_pts).astype(f32),
        close.astype(f32),
        vc_p,
        vc_n,
        vc_finger,
        n_init,
    )
