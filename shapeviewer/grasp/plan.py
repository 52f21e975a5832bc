"""GraspIt-style grasp planning on one object mesh (SPEC section 8).

Frames: the world frame has the table top as z = 0 (+z up); the palm frame is the hand's (origin at
the centre of the palm face, +z the approach). ``T_world_palm`` maps palm to world coordinates.
Units: metres and radians.

:func:`plan_grasps` works in two stages.

1. A cheap search without physics. A candidate is a palm orientation ``R`` (its approach
   ``R[:, 2]`` never points up, so the hand never comes from below the table), an aim point the
   approach line passes through, and a preshape (the Barrett's spread). Its palm position is where
   the open hand, moved along the approach from far away, first touches the object (rays cast from
   the front of the hand at the object's surface inflated by a few millimetres, so that the hand
   does not skim past it); every finger then closes until it touches the object or the table (a
   signed-distance grid of the object looked up at finger surface samples precomputed over the
   closing range). Its energy is GraspIt's contact energy of the hand's virtual contacts in that
   closed state: the mean over contacts of the distance to the object plus 50 mm per unit of
   (1 - cos) misalignment of the contact normal. Random candidates are refined by simulated
   annealing (parallel chains, one vectorised evaluation per step).
2. The best distinct candidates run the execution protocol in the pybullet world
   (:func:`approach_and_close`: back off, approach until contact, close), which gives each grasp's
   planned palm pose, joints and contacts; epsilon and volume come from those contacts. Grasps
   that start in collision, touch the table, or leave a finger without object contact are dropped.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from functools import cache
from typing import Callable, Sequence

import numpy as np
import open3d as o3d
import pybullet as p
import trimesh
from scipy import ndimage
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from skimage import measure

from shapeviewer.grasp.hands import Hand, get_hand, pose_to_pq
from shapeviewer.grasp.quality import GraspQuality, grasp_quality, max_radius
from shapeviewer.grasp.world import ApproachResult, CloseResult, Contact, Decomposition, GraspWorld

BACK_OFF = 0.2  # m: the protocol backs the open hand off this far along the approach (SPEC section 8)
APPROACH_SLACK = 0.03  # m: planning approaches this much beyond the back-off, for cheap-stage errors
DISTINCT_POSITION = 0.01  # m: grasps closer than this in palm position ...
DISTINCT_ANGLE = math.radians(15.0)  # ... and in palm orientation are the same grasp
ALIGN_WEIGHT = 0.05  # m per unit of (1 - cos): GraspIt's contact energy adds 100 mm / 2 per unit
APPROACH_MARGIN = 0.004  # m: the cheap approach keeps the hand this far from the object until it stops
TABLE_CLEARANCE = 0.003  # m: the open hand must stay this far above the table
APPROACH_SPACING = 0.005  # m between the lines of the approach rays (about the margin: nothing slips through)
CLOSE_SPACING = 0.01  # m between hand surface samples for closing and the table (most of the evaluation cost)
PRESHAPE_STEP = math.radians(7.5)  # grid of the Barrett spread in the cheap stage
CLOSE_STEPS = 15  # closing fractions 0..1 at which finger samples are precomputed (10 deg for the Barrett)
FIELD_MARGIN = 0.04  # m around the object covered by its signed-distance grid; farther counts as this far
FIELD_CELLS = 150_000  # signed-distance grid size cap
FIELD_MIN_STEP = 0.0025  # m: finest signed-distance grid step
BATCH = 256  # candidates per vectorised evaluation

ProgressFn = Callable[[float], None]
CancelFn = Callable[[], bool]


# ---------------------------------------------------------------------------------------------
# Results.

@dataclass(frozen=True, eq=False)
class GraspContact:
    """A hand link touching the object: ``position`` on the object's surface and the object's
    outward unit ``normal`` there (both world frame, metres)."""

    link: str
    position: np.ndarray
    normal: np.ndarray

    @staticmethod
    def from_world(c: Contact) -> "GraspContact":
        return GraspContact(c.link, np.asarray(c.position, float), np.asarray(c.normal, float))


@dataclass(eq=False)
class Grasp:
    """A planned grasp.

    ``T_world_palm``: 4x4 palm pose (world frame, metres). ``dofs``: the hand's actuated values by
    ``hand.dof_names`` (radians; metres for the Panda's fingers); ``joints``: every movable URDF
    joint by ``hand.joint_names``, the full state (after a Barrett breakaway the distal joints are
    ahead of their coupled values). ``contacts``: where the closed hand touches the object.
    ``epsilon``/``volume``: GraspIt's qualities of those contacts (see :mod:`quality`).
    ``energy``: GraspIt's contact energy (m) of the virtual contacts in this state (lower is better).
    """

    hand: str
    T_world_palm: np.ndarray
    dofs: dict[str, float]
    joints: dict[str, float]
    contacts: tuple[GraspContact, ...]
    epsilon: float
    volume: float
    energy: float
    frame: str = "world"

    @property
    def position(self) -> np.ndarray:
        """Palm position (world frame, m)."""
        return self.T_world_palm[:3, 3].copy()

    @property
    def quaternion_xyzw(self) -> np.ndarray:
        """Palm orientation as a unit quaternion (x, y, z, w), world frame."""
        return np.asarray(pose_to_pq(self.T_world_palm)[1])

    @property
    def approach(self) -> np.ndarray:
        """Approach direction (unit, world frame)."""
        return self.T_world_palm[:3, :3] @ np.asarray(get_hand(self.hand).approach, float)

    @property
    def force_closure(self) -> bool:
        return self.epsilon > 0.0


# ---------------------------------------------------------------------------------------------
# Hand samples precomputed in the palm frame.

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
        count = max(int(math.ceil(mesh.area / spacing ** 2)), 1)
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
    mesh = trimesh.util.concatenate(parts)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                        o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
    (x0, y0, _), (x1, y1, z1) = mesh.bounds
    xs = np.arange(x0, x1 + APPROACH_SPACING, APPROACH_SPACING)
    ys = np.arange(y0, y1 + APPROACH_SPACING, APPROACH_SPACING)
    xy = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2)
    origins = np.hstack([xy, np.full((len(xy), 1), z1 + 0.01)])
    rays = np.hstack([origins, np.tile([0.0, 0.0, -1.0], (len(xy), 1))]).astype(np.float32)
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    hit = np.isfinite(t)
    return origins[hit] - t[hit, None] * [0.0, 0.0, 1.0]


def _pad(arrays: list[np.ndarray]) -> np.ndarray:
    """Stack point sets of different sizes, repeating each set's first point (harmless for minima)."""
    n = max(len(a) for a in arrays)
    return np.stack([np.vstack([a, np.repeat(a[:1], n - len(a), axis=0)]) for a in arrays])


@dataclass(frozen=True, eq=False)
class _HandSamples:
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


def _preshape_dofs(hand: Hand) -> list[int]:
    """Dofs that closing leaves alone (the Barrett's spread)."""
    return [i for i in range(len(hand.dof_names)) if hand.dof_open[i] == hand.dof_closed[i]]


@cache
def _hand_samples(name: str) -> _HandSamples:
    hand = get_hand(name)
    pre = _preshape_dofs(hand)
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
    return _HandSamples(preshapes, _pad(approach_pts).astype(f32), _pad(body_pts).astype(f32), close.astype(f32),
                        vc_p, vc_n, vc_finger, n_init)


# ---------------------------------------------------------------------------------------------
# The object: a signed-distance grid and a ray-casting scene.

class ObjectField:
    """Signed distance (m, negative inside) and its gradient around a mesh (world frame), on a
    grid of step ``h`` covering the bounds plus ``FIELD_MARGIN``.

    Inside/outside comes from ray parity (voting over three rays, which tolerates small holes in a
    mesh that is not watertight); distances from a Euclidean distance transform of that grid,
    replaced near the surface by the distance to dense surface samples (accurate to about a
    millimetre). Points off the grid read the border values, at least about the margin.
    Approach rays hit the surface ``APPROACH_MARGIN`` outside the object (marching cubes of the grid).
    """

    def __init__(self, mesh: trimesh.Trimesh, seed: int = 0):
        self.mesh = mesh
        self.com = np.asarray(mesh.center_mass if mesh.is_watertight else mesh.centroid, float)
        self.max_radius = max_radius(mesh.vertices, self.com)
        lo = mesh.bounds[0] - FIELD_MARGIN
        hi = mesh.bounds[1] + FIELD_MARGIN
        self.h = h = max(FIELD_MIN_STEP, float(np.prod(hi - lo) / FIELD_CELLS) ** (1 / 3))
        shape = np.ceil((hi - lo) / h).astype(int) + 1
        self.origin = lo
        self.shape = shape
        axes = [lo[i] + h * np.arange(shape[i]) for i in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                            o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
        votes = 1 if mesh.is_watertight else 3
        inside = (scene.compute_occupancy(o3d.core.Tensor(grid.astype(np.float32)), nsamples=votes)
                  .numpy() > 0.5).reshape(shape)
        # Node-to-node distances to the other side put the surface about half a step away.
        sd = np.where(inside, 0.5 * h - h * ndimage.distance_transform_edt(inside),
                      h * ndimage.distance_transform_edt(~inside) - 0.5 * h).reshape(-1)
        # A k-d tree query is cheap near the samples and slow far from them: only the band.
        band = np.flatnonzero(np.abs(sd) < 2.5 * h)
        n_samples = int(np.clip(mesh.area / 1e-6, 5_000, 40_000))  # about one per mm^2
        samples, _ = trimesh.sample.sample_surface(mesh, n_samples, seed=seed)
        dist, _ = cKDTree(samples).query(grid[band])
        sd[band] = np.where(inside.reshape(-1)[band], -dist, dist)
        self.sd = sd = np.clip(sd, -FIELD_MARGIN, FIELD_MARGIN).reshape(shape).astype(np.float32)
        self.grad = np.stack(np.gradient(sd, h), axis=-1).astype(np.float32)
        # The approach casts rays at the surface offset by APPROACH_MARGIN: a hand sliding past
        # the object closer than that (which the exact rays would allow, and pybullet's slightly
        # padded convex parts would not) counts as touching it.
        verts, faces_, _, _ = measure.marching_cubes(sd, level=APPROACH_MARGIN, spacing=(self.h,) * 3)
        self.offset_scene = o3d.t.geometry.RaycastingScene()
        self.offset_scene.add_triangles(o3d.core.Tensor((verts + lo).astype(np.float32)),
                                        o3d.core.Tensor(faces_.astype(np.uint32)))

    def _corners(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat indices (N x 8) of the grid cell corners around each point and their weights (N x 8)."""
        f = (np.asarray(points, np.float32).reshape(-1, 3) - self.origin.astype(np.float32)) / np.float32(self.h)
        f = np.clip(f, 0.0, (self.shape - 1) - 1e-3)
        i = f.astype(np.int64)
        t = f - i
        ny, nz = self.shape[1], self.shape[2]
        base = (i[:, 0] * ny + i[:, 1]) * nz + i[:, 2]
        idx, w = [], []
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    idx.append(base + (dx * ny + dy) * nz + dz)
                    w.append((t[:, 0] if dx else 1 - t[:, 0]) * (t[:, 1] if dy else 1 - t[:, 1])
                             * (t[:, 2] if dz else 1 - t[:, 2]))
        return np.stack(idx, axis=1), np.stack(w, axis=1)

    def nearest_signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (m) of the grid node nearest each point (... x 3, world frame): within
        about ``h`` of the exact value, one lookup per point where interpolation takes eight."""
        f = (np.asarray(points, np.float32) - self.origin.astype(np.float32)) * np.float32(1.0 / self.h)
        i = np.rint(f).astype(np.int32)
        np.minimum(np.maximum(i, 0, out=i), (self.shape - 1).astype(np.int32), out=i)
        return self.sd.reshape(-1)[(i[..., 0] * self.shape[1] + i[..., 1]) * self.shape[2] + i[..., 2]]

    def distance_and_normal(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (m) and the outward unit normal (gradient direction) at ``points``."""
        idx, w = self._corners(points)
        sd = np.einsum("ij,ij->i", self.sd.reshape(-1)[idx], w)
        g = np.einsum("ijk,ij->ik", self.grad.reshape(-1, 3)[idx], w)
        g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-9)
        lead = np.shape(points)[:-1]
        return sd.reshape(lead), g.reshape(*lead, 3)

    def offset_ray_hits(self, origins: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """Distance (m) along unit ``direction`` (... x 3, broadcast) from each origin to the
        surface APPROACH_MARGIN outside the object; inf on a miss."""
        o = np.asarray(origins, np.float32).reshape(-1, 3)
        d = np.broadcast_to(np.asarray(direction, np.float32), np.shape(origins)).reshape(-1, 3)
        rays = o3d.core.Tensor(np.ascontiguousarray(np.hstack([o, d])))
        return self.offset_scene.cast_rays(rays)["t_hit"].numpy().reshape(np.shape(origins)[:-1])

    def contact_energy(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """GraspIt's contact energy (m) of virtual contacts (... x V x 3 points and hand-outward
        normals, world frame): mean over V of |distance| + ALIGN_WEIGHT * (1 - cos) between the
        contact normal and the direction into the object."""
        sd, n_obj = self.distance_and_normal(points)
        cos = -np.einsum("...i,...i->...", normals, n_obj)
        return np.mean(np.minimum(np.abs(sd), FIELD_MARGIN) + ALIGN_WEIGHT * (1.0 - cos), axis=-1)


# ---------------------------------------------------------------------------------------------
# The cheap stage.

@dataclass
class _Candidates:
    """A batch of cheap-stage states and their evaluation (world frame).

    ``R`` (N x 3 x 3) palm orientations, ``aim`` (N x 3) points on the approach lines, ``shape``
    (N,) preshape indices, ``palm`` (N x 3) palm positions at first contact and ``energy`` (N,)
    (inf: the hand misses the object, meets the table, or approaches from below it).
    """

    R: np.ndarray
    aim: np.ndarray
    shape: np.ndarray
    palm: np.ndarray
    energy: np.ndarray

    def take(self, idx) -> "_Candidates":
        return _Candidates(self.R[idx], self.aim[idx], self.shape[idx], self.palm[idx], self.energy[idx])

    @staticmethod
    def concat(parts: Sequence["_Candidates"]) -> "_Candidates":
        return _Candidates(*(np.concatenate([getattr(part, k) for part in parts])
                             for k in ("R", "aim", "shape", "palm", "energy")))


def _evaluate(obj: ObjectField, hs: _HandSamples, R: np.ndarray, aim: np.ndarray, shape: np.ndarray,
              table: bool, start_distance: float) -> tuple[np.ndarray, np.ndarray]:
    """Palm positions (N x 3) and energies (N,) of candidates (see the module docstring)."""
    n = len(R)
    d = R[:, :, 2]
    start = aim - start_distance * d
    Rt = np.transpose(R, (0, 2, 1))
    Rt32 = Rt.astype(np.float32)
    front = hs.approach_pts[shape] @ Rt32 + start[:, None, :].astype(np.float32)
    travel = obj.offset_ray_hits(front, d[:, None, :]).min(axis=1)
    ok = np.isfinite(travel)
    # From the offset surface the hand has at least the margin left to go; stop a contact
    # tolerance short of that, as the pybullet approach stops short of contact.
    palm = start + np.where(ok, travel + APPROACH_MARGIN - 1e-3, 0.0)[:, None] * d
    if table:
        body_z = np.einsum("nj,npj->np", R[:, 2, :].astype(np.float32), hs.body_pts[shape]) + palm[:, 2:3]
        ok &= body_z.min(axis=1) >= TABLE_CLEARANCE
    # Close every finger until its samples first reach into the object or below the table.
    pts = hs.close_pts[shape]  # N x F x U x Q x 3
    nf, nu, nq = pts.shape[1:4]
    world = (pts.reshape(n, -1, 3) @ Rt32 + palm[:, None, :].astype(np.float32)).reshape(n, nf, nu, nq, 3)
    clearance = obj.nearest_signed_distance(world).min(axis=-1)
    if table:
        clearance = np.minimum(clearance, world[..., 2].min(axis=-1))
    hit = clearance < 0.0
    first = np.where(hit.any(axis=-1), hit.argmax(axis=-1), nu)  # N x F
    # Interpolate the closing fraction where the clearance crosses zero.
    k0 = np.clip(first - 1, 0, nu - 1)
    k1 = np.clip(first, 0, nu - 1)
    c0 = np.take_along_axis(clearance, k0[..., None], -1)[..., 0]
    c1 = np.take_along_axis(clearance, k1[..., None], -1)[..., 0]
    frac = np.where(first > 0, np.clip(c0 / np.maximum(c0 - c1, 1e-9), 0.0, 1.0), 0.0)
    step = np.where((first > 0) & (first < nu), k0 + frac, np.where(first == 0, 0.0, nu - 1.0))  # N x F
    # Virtual contacts at each finger's stop (the palm's do not move).
    vc_step = np.where(hs.vc_finger[None, :] >= 0, step[:, np.maximum(hs.vc_finger, 0)], 0.0)  # N x V
    lo = np.clip(np.floor(vc_step).astype(int), 0, nu - 2)
    t = (vc_step - lo)[..., None]
    v = np.arange(len(hs.vc_finger))[None, :]
    s = shape[:, None]
    vc_p = (1 - t) * hs.vc_pos[s, lo, v] + t * hs.vc_pos[s, lo + 1, v]
    vc_n = (1 - t) * hs.vc_nrm[s, lo, v] + t * hs.vc_nrm[s, lo + 1, v]
    vc_p = vc_p @ Rt + palm[:, None, :]
    vc_n = vc_n @ Rt
    energy = obj.contact_energy(vc_p, vc_n / np.linalg.norm(vc_n, axis=-1, keepdims=True))
    return palm, np.where(ok, energy, np.inf)


def _frames(d: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """Rotations (N x 3 x 3) whose z axis is the unit ``d`` and x axis turned by ``roll`` about it."""
    helper = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(d, e1)
    x = np.cos(roll)[:, None] * e1 + np.sin(roll)[:, None] * e2
    return np.stack([x, np.cross(d, x), d], axis=2)


def _allowed(R: np.ndarray, table: bool) -> np.ndarray:
    """With a table, approaches may be horizontal or downwards, never upwards from below it."""
    return R[:, 2, 2] <= 1e-9 if table else np.ones(len(R), bool)


def _distinct(positions: np.ndarray, rotations: np.ndarray, order: Sequence[int], limit: int) -> list[int]:
    """Indices from ``order`` (best first), skipping any within DISTINCT_POSITION and
    DISTINCT_ANGLE of one already kept, at most ``limit``."""
    kept: list[int] = []
    for i in order:
        if kept:
            dp = np.linalg.norm(positions[kept] - positions[i], axis=1)
            cos = (np.einsum("kij,ij->k", rotations[kept], rotations[i]) - 1.0) / 2.0
            if np.any((dp <= DISTINCT_POSITION) & (cos >= math.cos(DISTINCT_ANGLE))):
                continue
        kept.append(int(i))
        if len(kept) >= limit:
            break
    return kept


# ---------------------------------------------------------------------------------------------
# The pybullet stage.

def approach_and_close(world: GraspWorld, T_world_palm: np.ndarray, preshape: Sequence[float], *,
                       back_off: float = BACK_OFF, max_approach: float = BACK_OFF,
                       targets: Sequence[Sequence[float] | None] = (None,)
                       ) -> tuple[bool, ApproachResult, CloseResult | None]:
    """The protocol of SPEC section 8 on the hand of ``world``.

    Set the palm at ``T_world_palm`` (world frame) with the dofs ``preshape`` and open the hand;
    back off ``back_off`` (m) along the approach (poses are set directly, so nothing collides on
    the way: the protocol's "collisions off"); approach up to ``max_approach`` (m) until contact;
    then close towards each of ``targets`` in turn (dof vectors; None: fully closed), each
    stopping fingers at contact. Returns whether the backed-off start was clear of every obstacle,
    the approach, and the last closing (None without targets).
    """
    world.set_dofs(preshape)
    world.open_hand()
    world.set_palm_pose(T_world_palm)
    world.move_along_approach(-back_off)
    clear = not world.in_collision(world.contact_tol)
    approach = world.approach(max_approach)
    closed = None
    for target in targets:
        closed = world.close_fingers(target)
    return clear, approach, closed


def object_contacts(closed: CloseResult, body: int, com: np.ndarray, radius: float
                    ) -> tuple[tuple[GraspContact, ...], GraspQuality]:
    """The closed hand's contacts with object ``body`` and their qualities, for the object's
    centre of mass ``com`` (world frame) and max radius (m); no contacts: (0, 0)."""
    contacts = tuple(GraspContact.from_world(c) for c in closed.contacts if c.body == body)
    return contacts, grasp_quality([c.position for c in contacts], [c.normal for c in contacts], com, radius)


def _grasp_from_world(world: GraspWorld, body: int, obj: ObjectField, closed: CloseResult) -> Grasp:
    """The hand's current state in ``world`` as a :class:`Grasp` on object ``body`` (qualities
    from its contacts, energy from ``obj``, the same object's field)."""
    hand = world.hand.hand
    T = world.palm_pose()
    contacts, q = object_contacts(closed, body, obj.com, obj.max_radius)
    vc_p, vc_n = hand.virtual_contacts_palm(closed.joints)
    energy = float(obj.contact_energy(vc_p @ T[:3, :3].T + T[:3, 3], vc_n @ T[:3, :3].T))
    return Grasp(hand.name, T, dict(zip(hand.dof_names, map(float, closed.dofs))),
                 dict(zip(hand.joint_names, map(float, closed.joints))), contacts, q.epsilon, q.volume, energy)


def _table_gap(world: GraspWorld, radius: float) -> float:
    """Smallest hand-table distance (m), or ``radius`` when farther (no table: inf)."""
    if world.table is None:
        return math.inf
    rows = p.getClosestPoints(world.hand.body, world.table, radius, physicsClientId=world.client)
    return min((r[8] for r in rows), default=radius)


def _fingers_touch(hand: Hand, contacts: Sequence[GraspContact]) -> bool:
    links = {c.link for c in contacts}
    return all(links & set(f.links) for f in hand.fingers)


# ---------------------------------------------------------------------------------------------
# Planning.

@dataclass(frozen=True)
class PlanSettings:
    """Search sizes. ``samples``: random candidates; ``chains`` x ``steps``: annealing;
    ``simulate``: candidates executed in pybullet (at least 3 per requested grasp; more when
    fewer than the requested number reach force closure); ``t_start``/``t_end``: annealing
    temperatures (m of energy)."""

    samples: int = 1024
    chains: int = 64
    steps: int = 150
    simulate: int = 60
    t_start: float = 0.01
    t_end: float = 0.0005


@dataclass(frozen=True)
class PlanStats:
    """What planning did: cheap evaluations and their rate (per second of search), candidates
    executed in pybullet, seconds per stage, and whether it was cancelled."""

    evaluations: int
    evaluations_per_second: float
    simulated: int
    seconds: dict[str, float]
    cancelled: bool


@dataclass(frozen=True)
class PlanResult:
    """The grasps :func:`plan` found (best first) and what it did."""

    grasps: list[Grasp]
    stats: PlanStats


def plan_grasps(mesh_world: trimesh.Trimesh, hand: str = "barrett", n_grasps: int = 20, seed: int = 0,
                table: bool = True, budget_seconds: float | None = None, progress: ProgressFn | None = None,
                cancel: CancelFn | None = None) -> list[Grasp]:
    """Up to ``n_grasps`` distinct grasps of ``mesh_world``, best first (see :func:`plan`)."""
    return plan(mesh_world, hand, n_grasps, seed, table, budget_seconds, progress, cancel).grasps


def plan(mesh_world: trimesh.Trimesh, hand: str = "barrett", n_grasps: int = 20, seed: int = 0,
         table: bool = True, budget_seconds: float | None = None, progress: ProgressFn | None = None,
         cancel: CancelFn | None = None, settings: PlanSettings = PlanSettings()) -> PlanResult:
    """Up to ``n_grasps`` distinct grasps of ``mesh_world`` (world frame, metres, standing on the
    table z = 0 when ``table``), best first: force-closure grasps by epsilon, then the rest.

    Deterministic for a seed unless ``budget_seconds`` (wall-clock limit: the search gets up to
    45% of it, the simulation the rest) or ``cancel`` (polled often; planning then returns the
    grasps simulated so far) cut it short. ``progress(fraction)`` reports 0..1.

    Raises:
        DecompositionError: the object's convex decomposition failed or was not ready within the
            budget (or :data:`~shapeviewer.grasp.world.VHACD_TIMEOUT` without one).
    """
    t0 = time.perf_counter()
    report = progress or (lambda _f: None)
    stopped = cancel or (lambda: False)

    def over(share: float) -> bool:
        return budget_seconds is not None and time.perf_counter() > t0 + share * budget_seconds

    rng = np.random.default_rng(seed)
    hand_ = get_hand(hand)
    seconds: dict[str, float] = {}
    # V-HACD runs in a child process: let it overlap the cheap stage. A cancelled plan does not
    # wait for it (it still completes the cache for the next one, within its own time bound); a
    # failed or interrupted one kills it.
    decomposition = Decomposition(mesh_world)
    try:
        hs = _hand_samples(hand)
        obj = ObjectField(mesh_world, seed)
        seconds["setup"] = time.perf_counter() - t0
        t1 = time.perf_counter()
        found, evaluations, cancelled = _search(obj, hs, rng, table, settings, report, stopped, lambda: over(0.45))
        seconds["search"] = time.perf_counter() - t1
        if not cancelled:
            # Within the budget when there is one (a grasp needs the decomposition: none without it).
            left = None if budget_seconds is None else max(1.0, t0 + budget_seconds - time.perf_counter())
            decomposition.wait(left)
    except BaseException:
        decomposition.cancel()
        raise

    t2 = time.perf_counter()
    grasps: list[Grasp] = []
    simulated = 0
    if not cancelled:
        order = np.argsort(found.energy, kind="stable")
        order = order[np.isfinite(found.energy[order])]
        n_sim = max(settings.simulate, 3 * n_grasps)
        picks = _distinct(found.palm, found.R, order, 3 * n_sim)
        with GraspWorld(hand_, table=table) as world:
            body = world.add_object(mesh_world, decompose=True)
            for j, i in enumerate(picks):
                if (j >= n_sim and len(_best_distinct(grasps, n_grasps, force_closure=True)) >= n_grasps) \
                        or over(0.95):
                    break
                if stopped():
                    cancelled = True
                    break
                T = np.eye(4)
                T[:3, :3] = found.R[i]
                T[:3, 3] = found.palm[i]
                clear, _, closed = approach_and_close(world, T, hs.preshapes[found.shape[i]],
                                                      max_approach=BACK_OFF + APPROACH_SLACK)
                simulated += 1
                report(0.5 + 0.5 * min(1.0, (j + 1) / n_sim))
                # Reject a start in collision and any touch of the table (by the approach or a finger).
                if not clear or _table_gap(world, 2 * world.contact_tol) <= world.contact_tol:
                    continue
                g = _grasp_from_world(world, body, obj, closed)
                if _fingers_touch(hand_, g.contacts):
                    grasps.append(g)
    seconds["simulate"] = time.perf_counter() - t2
    seconds["total"] = time.perf_counter() - t0
    report(1.0)
    rate = evaluations / max(seconds["search"], 1e-9)
    return PlanResult(_best_distinct(grasps, n_grasps), PlanStats(evaluations, rate, simulated, seconds, cancelled))


def _best_distinct(grasps: list[Grasp], n: int, force_closure: bool = False) -> list[Grasp]:
    """Up to ``n`` distinct grasps, best first: force closure, then epsilon, volume, energy."""
    ranked = sorted((g for g in grasps if g.force_closure or not force_closure),
                    key=lambda g: (-g.force_closure, -g.epsilon, -g.volume, g.energy))
    keep = _distinct(np.array([g.position for g in ranked]).reshape(-1, 3),
                     np.array([g.T_world_palm[:3, :3] for g in ranked]).reshape(-1, 3, 3), range(len(ranked)), n)
    return [ranked[i] for i in keep]


def _search(obj: ObjectField, hs: _HandSamples, rng: np.random.Generator, table: bool, settings: PlanSettings,
            report: ProgressFn, stopped: CancelFn, out_of_time: Callable[[], bool]
            ) -> tuple[_Candidates, int, bool]:
    """The cheap stage: random candidates, then simulated annealing from the best distinct ones.
    Returns every state evaluated, the number of evaluations, and whether it was cancelled."""
    extent = np.asarray(obj.mesh.extents, float)
    centre = np.asarray(obj.mesh.bounds.mean(axis=0), float)
    # Far enough that the open hand starts clear of the object wherever the aim point is.
    start_distance = 2.0 * float(np.linalg.norm(extent)) + 0.3
    evaluations = 0

    def evaluate(R: np.ndarray, aim: np.ndarray, shape: np.ndarray) -> _Candidates:
        nonlocal evaluations
        palm, energy = np.zeros((len(R), 3)), np.full(len(R), np.inf)
        allowed = np.flatnonzero(_allowed(R, table))
        for i in range(0, len(allowed), BATCH):
            sl = allowed[i:i + BATCH]
            palm[sl], energy[sl] = _evaluate(obj, hs, R[sl], aim[sl], shape[sl], table, start_distance)
        evaluations += len(allowed)
        return _Candidates(R, aim, shape, palm, energy)

    # Random candidates: approach directions over the sphere (folded to point down onto the
    # table), aim points around the object's centre, random roll and preshape.
    n0 = settings.samples
    d = rng.normal(size=(n0, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    if table:
        d[:, 2] = -np.abs(d[:, 2])
    first = evaluate(_frames(d, rng.uniform(0, 2 * np.pi, n0)), centre + rng.normal(size=(n0, 3)) * 0.35 * extent,
                     rng.integers(0, hs.n_init, n0))
    found = [first]
    report(0.05)
    order = np.argsort(first.energy, kind="stable")
    order = order[np.isfinite(first.energy[order])]
    starts = _distinct(first.palm, first.R, order, settings.chains)
    if not starts:
        return first, evaluations, stopped()
    chains = first.take(np.array(starts))
    n_c = len(chains.R)
    for k in range(settings.steps):
        if stopped():
            return _Candidates.concat(found), evaluations, True
        if out_of_time():
            break
        temp = settings.t_start * (settings.t_end / settings.t_start) ** (k / max(settings.steps - 1, 1))
        # Steps shrink with the temperature, down to a floor that keeps the chains moving.
        scale = max(math.sqrt(temp / settings.t_start), 0.15)
        R = Rotation.from_rotvec(rng.normal(size=(n_c, 3)) * 0.25 * scale).as_matrix() @ chains.R
        aim = chains.aim + rng.normal(size=(n_c, 3)) * 0.15 * extent * scale
        shape = np.clip(chains.shape + np.rint(rng.normal(size=n_c) * 3 * scale).astype(int), 0, len(hs.preshapes) - 1)
        proposal = evaluate(R, aim, shape)
        found.append(proposal)
        delta = proposal.energy - chains.energy
        accept = np.isfinite(proposal.energy) & (
            (delta <= 0) | (rng.random(n_c) < np.exp(-np.clip(delta, 0, None) / temp)))
        for name in ("R", "aim", "shape", "palm", "energy"):
            getattr(chains, name)[accept] = getattr(proposal, name)[accept]
        report(0.05 + 0.45 * (k + 1) / settings.steps)
    return _Candidates.concat(found), evaluations, False
