"""Tabletop views: one object resting on a table among neighbours, seen by a robot's depth camera.

This is how completion is used on a robot, and what the paper's floating views on a view sphere
are not: the object rests in a stable pose on a support plane (which hides its bottom), neighbours
may occlude it, the camera sits where a robot's head or wrist camera would (20-70 degrees above the
table, 0.4-1.2 m away), the depth sensor is a Kinect or a RealSense (:mod:`shapeviewer.perception.camera`),
and the segment is what the app's own segmentation (:func:`segment.segment_scene`) cuts out of the
frame, not a perfect mask. Training data (``shapeviewer generate --scenes tabletop``) and the
``tabletop`` evaluation set use the same views.

Frames: the world frame has z up with the table top at z = 0 (metres); the target object's frame
is its catalogue mesh centred on its bounding-box centre (:func:`catalogue.centred_mesh`);
everything returned is in the camera optical frame (x right, y down, z forward, metres).
Every random choice comes from ``(seed, object, view)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import trimesh

from ..perception.camera import Intrinsics, backproject, look_at, transform_points
from ..perception.capture import Capture
from . import catalogue
from .sensor import RaycastRenderer, noise_model

ELEVATION_DEG = (20.0, 70.0)  # camera above the table plane, seen from the target
DISTANCE = (0.4, 1.2)  # metres from the camera to the target's centre
NEIGHBOURS = (0, 3)  # how many other objects stand around the target (inclusive)
NEIGHBOUR_GAP = (0.03, 0.12)  # metres between footprints: segmentation separates them
OCCLUDER_SHARE = 0.5  # share of neighbours placed between the camera and the target
MIN_POSE_PROBABILITY = 0.02  # stable poses rarer than this are not drawn
SENSORS = ("kinect", "realsense")
MIN_TARGET_PIXELS = 150  # views showing fewer target points in its segment are rejected
MIN_TARGET_SHARE = 0.6  # the segment must be mostly the target
TABLE_HALF_SIZE = 1.5  # metres


def sensor_intrinsics(sensor: str) -> Intrinsics:
    """640x480 intrinsics of the simulated sensor (RealSense D435 depth at 640x480: fx = fy = 385 is
    its wide stereo imager; aligned to colour it is about 615)."""
    if sensor == "realsense":
        return Intrinsics(640, 480, 615.0, 615.0, 319.5, 239.5)
    return Intrinsics.kinect()


@dataclass
class TabletopView:
    """One rendered and segmented tabletop view of a target object.

    Attributes:
        name: the target's catalogue name; ``view``: its view number; ``sensor``: ``kinect`` or ``realsense``.
        points_cam: (N, 3) the target's segment (camera frame, metres), as segmentation cut it.
        plane_cam: (4,) the support plane the segmentation found (camera frame, unit normal towards
            the camera), or None when it found none.
        T_cam_obj: 4x4 pose of the target mesh (object frame) in the camera frame.
        mesh: the target mesh in its object frame (metres).
        neighbours: catalogue names of the other objects on the table.
        target_share: share of the segment's points that belong to the target.
        capture: the whole frame (organized, with per-pixel labels: 0 = target).
    """

    name: str
    view: int
    sensor: str
    points_cam: np.ndarray
    plane_cam: np.ndarray | None
    T_cam_obj: np.ndarray
    mesh: trimesh.Trimesh
    neighbours: list[str] = field(default_factory=list)
    target_share: float = 1.0
    capture: Capture | None = None

    def truth_cam(self) -> trimesh.Trimesh:
        """The target's true mesh in the camera frame (metres)."""
        return self.mesh.copy().apply_transform(self.T_cam_obj)


@lru_cache(maxsize=16)
def stable_poses(name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(transforms (K, 4, 4), probabilities (K,))``: how the centred mesh of ``name`` rests on a
    plane z = 0 (quasi-static drop probabilities of its convex hull's faces), rarer ones dropped."""
    mesh = catalogue.centred_mesh(name)
    T, p = trimesh.poses.compute_stable_poses(mesh.convex_hull, center_mass=mesh.center_mass, n_samples=1)
    keep = p >= MIN_POSE_PROBABILITY
    if not keep.any():
        keep = p >= p.max()
    return np.asarray(T)[keep], np.asarray(p)[keep] / p[keep].sum()


def _resting_pose(name: str, rng: np.random.Generator, xy: np.ndarray, stable: bool = True) -> np.ndarray:
    """``T_world_obj``: a drawn stable pose (or, with ``stable`` False, the catalogue's own
    orientation: cheaper, and fine for a neighbour), a random yaw, the footprint centred at ``xy``."""
    if stable:
        T, p = stable_poses(name)
        pose = T[int(rng.choice(len(p), p=p))]
    else:
        pose = np.eye(4)
    yaw = rng.uniform(-np.pi, np.pi)
    Rz = np.eye(4)
    Rz[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    out = Rz @ pose
    v = transform_points(out, catalogue.centred_mesh(name).vertices)
    out[:3, 3] += [
        xy[0] - (v[:, 0].min() + v[:, 0].max()) / 2,
        xy[1] - (v[:, 1].min() + v[:, 1].max()) / 2,
        -v[:, 2].min(),
    ]
    return out


def _footprint_radius(name: str, T_world_obj: np.ndarray) -> float:
    """Radius (m) of the circle around the x-y bounding-box centre that holds the posed mesh."""
    v = transform_points(T_world_obj, catalogue.centred_mesh(name).vertices)[:, :2]
    return float(np.linalg.norm(v - (v.min(0) + v.max(0)) / 2, axis=1).max())


def render_tabletop_view(
    name: str,
    view: int,
    *,
    seed: int = 0,
    sensor: str | None = None,
    neighbour_pool: list[str] | None = None,
    tries: int = 4,
    noise_scale: float = 1.0,
) -> TabletopView | None:
    """Render and segment view ``view`` of ``name`` resting on a table; None if no usable view came out.

    Args:
        name: the target's catalogue name.
        view: view number (any int); with ``seed`` and ``name`` it fixes every random choice.
        seed: the random seed.
        sensor: ``kinect`` or ``realsense``; None draws one.
        neighbour_pool: catalogue names neighbours are drawn from (default: every catalogue object
            of the target's split, so holdout models stand among holdout models).
        tries: camera/layout draws before giving up (a neighbour may hide the target).
        noise_scale: the sensor's depth error times this (:meth:`shapeviewer.sim.sensor.DepthNoise.scaled`).
    """
    from ..perception.segment import SegmentationError, segment_scene
    from .demo_scene import table_mesh

    rng = np.random.default_rng(catalogue.object_seed(name, seed, view, 11))
    sensor = sensor or SENSORS[int(rng.integers(len(SENSORS)))]
    intr = sensor_intrinsics(sensor)
    if neighbour_pool is None:
        split = catalogue.model_split(name)
        neighbour_pool = [
            e.name for e in catalogue.catalogue() if e.split == split and e.name != name and max(e.extents) <= 0.3
        ]
    for _ in range(tries):
        T_target = _resting_pose(name, rng, np.zeros(2))
        r_target = _footprint_radius(name, T_target)
        elevation = np.radians(rng.uniform(*ELEVATION_DEG))
        azimuth = rng.uniform(-np.pi, np.pi)
        toward_camera = np.array([np.cos(azimuth), np.sin(azimuth)])
        names, poses, radii = [name], [T_target], [r_target]
        for _ in range(int(rng.integers(NEIGHBOURS[0], NEIGHBOURS[1] + 1)) if neighbour_pool else 0):
            other = neighbour_pool[int(rng.integers(len(neighbour_pool)))]
            T = _resting_pose(other, rng, np.zeros(2), stable=False)
            r = _footprint_radius(other, T)
            for _ in range(20):  # a free spot around the target
                angle = (azimuth + rng.normal(0, 0.5)) if rng.random() < OCCLUDER_SHARE else rng.uniform(-np.pi, np.pi)
                spot = (r_target + r + rng.uniform(*NEIGHBOUR_GAP)) * np.array([np.cos(angle), np.sin(angle)])
                if all(np.linalg.norm(spot - q[:2, 3]) >= r + rq + NEIGHBOUR_GAP[0] for q, rq in zip(poses, radii)):
                    T[:2, 3] += spot
                    names.append(other)
                    poses.append(T)
                    radii.append(r)
                    break
        meshes_world = [catalogue.centred_mesh(n).copy().apply_transform(T) for n, T in zip(names, poses)]
        centre = (meshes_world[0].bounds[0] + meshes_world[0].bounds[1]) / 2
        distance = rng.uniform(*DISTANCE)
        eye = centre + distance * np.array(
            [np.cos(elevation) * toward_camera[0], np.cos(elevation) * toward_camera[1], np.sin(elevation)]
        )
        target = centre + rng.normal(0, 0.03, 3) * [1, 1, 0.3]
        T_world_cam = look_at(eye, target)
        renderer = RaycastRenderer([table_mesh(centre, TABLE_HALF_SIZE), *meshes_world])
        depth, gid = renderer.render(intr, T_world_cam, crop_to_objects=False)
        if not _fully_in_image(depth, gid):
            continue
        noise = noise_model(sensor)
        if noise is not None:
            depth = noise.scaled(noise_scale).apply(depth, rng)
        points = backproject(depth, intr)
        valid = np.isfinite(points).all(axis=-1)
        labels = np.where(valid & (gid > 0), gid - 1, -1).astype(np.int32)
        capture = Capture(
            points_cam=points, intrinsics=intr, source=f"tabletop({name}, view={view}, seed={seed})", labels=labels
        )
        try:
            seg = segment_scene(capture, seed=seed)
        except SegmentationError:
            continue
        flat = labels.reshape(-1)
        best, best_hits = None, 0
        for s in seg.segments:
            hits = int(np.count_nonzero(flat[s.indices] == 0))
            if hits > best_hits:
                best, best_hits = s, hits
        if best is None or best_hits < MIN_TARGET_PIXELS or best_hits < MIN_TARGET_SHARE * len(best.indices):
            continue
        T_cam_obj = np.linalg.inv(T_world_cam) @ T_target
        return TabletopView(
            name,
            int(view),
            sensor,
            best.points_cam,
            seg.plane_cam,
            T_cam_obj,
            catalogue.centred_mesh(name),
            names[1:],
            best_hits / len(best.indices),
            capture,
        )
    return None


def _fully_in_image(depth: np.ndarray, gid: np.ndarray, margin: int = 2) -> bool:
    """The target (geometry 1) shows and does not touch the image border."""
    target = gid == 1
    if not target.any():
        return False
    border = np.ones_like(target)
    border[margin:-margin, margin:-margin] = False
    return not bool((target & border).any())
