"""The app's default scene (the input of paper Fig. 5): a few graspable objects settled on a table by
pybullet and seen by a simulated Kinect.

Frames and units: the world frame has z up, metres, and the table top is the plane z = 0. Object
meshes are in their catalogue object frame (:mod:`shapeviewer.sim.catalogue`); ``T_world_obj`` maps them to
the world. The capture is in the camera optical frame (x right, y down, z forward, metres) with
``T_world_cam`` its pose in the world.

Everything is drawn from the seed: the same seed gives bitwise the same scene and cloud.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import trimesh
from pybullet_utils.bullet_client import BulletClient

from ..geometry import pose_to_pq
from ..grasp.hands import get_base_pose
from ..grasp.world import convex_decomposition
from ..perception.camera import Intrinsics, backproject, look_at, transform_points
from ..perception.capture import Capture, SceneObject
from ..runtime.bullet import direct_client, pybullet
from .catalogue import catalogue, load_mesh
from .sensor import KinectNoise, RaycastRenderer

# YCB objects that look like a tabletop and stand (or lie) stably; the bowl, mugs and cups are
# concave and show why completion needs more than a convex hull.
TABLETOP_YCB = (
    "ycb/002_master_chef_can",
    "ycb/003_cracker_box",
    "ycb/004_sugar_box",
    "ycb/005_tomato_soup_can",
    "ycb/006_mustard_bottle",
    "ycb/010_potted_meat_can",
    "ycb/011_banana",
    "ycb/013_apple",
    "ycb/016_pear",
    "ycb/019_pitcher_base",
    "ycb/021_bleach_cleanser",
    "ycb/024_bowl",
    "ycb/025_mug",
    "ycb/036_wood_block",
    "ycb/061_foam_brick",
    "ycb/065-h_cups",
    "ycb/077_rubiks_cube",
)
SIZE_RANGE = (0.05, 0.25)  # largest side (m): fits a hand
MIN_THICKNESS = 0.03  # smallest side (m): flat objects show the camera little more than a sliver
SPAWN_AREA = (0.5, 0.4)  # x, y size (m) of the table region the objects are spread over
MIN_GAP = 0.03  # free space (m) between settled objects, so that Euclidean clustering separates them
DROP_HEIGHT = 0.02  # objects start this far (m) above the table
DENSITY = 500.0  # kg/m^3; masses only matter for how objects settle
CONVEX_ENOUGH = 0.85  # mesh volume / hull volume above which one convex hull is a fine collision shape
TABLE_HALF_SIZE = 1.0  # the rendered table is a 2 x 2 m square around the objects
TIME_STEP = 1.0 / 240.0  # s
MAX_SETTLE_STEPS = 1200  # 5 simulated seconds
MAX_LAYOUTS = 20  # layouts tried before giving up on a set of objects

CAMERA_ELEVATION_DEG = (40.0, 55.0)  # below horizontal
CAMERA_DISTANCE = (0.8, 1.2)  # m from the objects' centre
CAMERA_AZIMUTH_DEG = (-115.0, -65.0)  # the camera looks across the table from the -y side
IMAGE_MARGIN_PX = 16  # objects stay this far inside the image border
MIN_VISIBLE_PX = 1000  # a camera pose is re-drawn when an object shows fewer ideal pixels
CAMERA_TRIES = 8

TABLE_RGB = (150, 138, 120)  # a neutral grey-brown table top
# The real colours of the curated YCB objects (roughly); the rest get a palette colour.
YCB_RGB = {
    "ycb/002_master_chef_can": (40, 95, 190),
    "ycb/003_cracker_box": (200, 45, 40),
    "ycb/004_sugar_box": (235, 205, 70),
    "ycb/005_tomato_soup_can": (190, 40, 40),
    "ycb/006_mustard_bottle": (235, 190, 40),
    "ycb/010_potted_meat_can": (45, 80, 165),
    "ycb/011_banana": (240, 205, 60),
    "ycb/013_apple": (185, 30, 35),
    "ycb/016_pear": (175, 190, 60),
    "ycb/019_pitcher_base": (50, 110, 200),
    "ycb/021_bleach_cleanser": (230, 230, 225),
    "ycb/024_bowl": (200, 50, 40),
    "ycb/025_mug": (200, 50, 40),
    "ycb/036_wood_block": (215, 175, 115),
    "ycb/061_foam_brick": (200, 60, 50),
    "ycb/065-h_cups": (60, 150, 75),
    "ycb/077_rubiks_cube": (60, 150, 75),
}
PALETTE_RGB = (  # distinct, plausible object colours
    (200, 45, 40),
    (40, 95, 190),
    (235, 190, 40),
    (60, 150, 75),
    (235, 120, 30),
    (140, 75, 165),
    (35, 155, 160),
    (225, 220, 205),
    (230, 120, 170),
    (70, 70, 75),
)
MIN_COLOUR_DISTANCE = 70  # RGB distance that tells two objects (or an object and the table) apart
AMBIENT = 0.35  # share of light that does not depend on the surface normal

# Independent random streams of one seed: which objects, the camera, the sensor noise.
_OBJECT_STREAM, _CAMERA_STREAM, _NOISE_STREAM = 0, 1, 2


# ----------------------------------------------------------------------------------------------
# Objects on the table


def tabletop_candidates() -> tuple[list[str], list[str]]:
    """Catalogue names a default scene draws from: (curated YCB, pybullet objects).

    Both keep to objects that fit a hand (largest side in ``SIZE_RANGE``) and are not flat
    (smallest side at least ``MIN_THICKNESS``).
    """

    def fits(extents: tuple) -> bool:
        return SIZE_RANGE[0] <= max(extents) <= SIZE_RANGE[1] and min(extents) >= MIN_THICKNESS

    entries = {e.name: e for e in catalogue()}
    ycb = [n for n in TABLETOP_YCB if n in entries and fits(entries[n].extents)]
    pyb = [e.name for e in entries.values() if e.source == "pybullet" and fits(e.extents)]
    return ycb, pyb


def pick_objects(rng: np.random.Generator, n_objects: int | None = None) -> list[str]:
    """4-6 (or ``n_objects``) distinct names, mostly YCB with one or two pybullet objects, in random order."""
    ycb, pyb = tabletop_candidates()
    n = int(rng.integers(4, 7)) if n_objects is None else n_objects
    n_pyb = min(int(rng.integers(1, 3)), max(n - 2, 0), len(pyb))
    names = list(rng.choice(ycb, n - n_pyb, replace=False)) + list(rng.choice(pyb, n_pyb, replace=False))
    return [str(names[i]) for i in rng.permutation(n)]


def build_tabletop(seed: int = 0, n_objects: int | None = None) -> list[SceneObject]:
    """Objects drawn by ``seed``, dropped on a table at z = 0 and settled by pybullet.

    Objects keep their catalogue orientation up to a random yaw (so they stand or lie as their mesh
    does) and start ``DROP_HEIGHT`` above the table, spread over ``SPAWN_AREA`` around the world
    origin. Layouts whose objects end up closer than ``MIN_GAP``, do not come to rest or roll away
    are re-drawn.

    Returns:
        one :class:`SceneObject` per object: its name, catalogue mesh (object frame, metres) and
        the settled pose ``T_world_obj``.
    """
    rng = np.random.default_rng([seed, _OBJECT_STREAM])
    names = pick_objects(rng, n_objects)
    meshes = [load_mesh(n) for n in names]
    client = direct_client()
    try:
        client.setGravity(0, 0, -9.81)
        client.setTimeStep(TIME_STEP)
        table = client.createMultiBody(0, client.createCollisionShape(pybullet.GEOM_PLANE))
        client.changeDynamics(table, -1, lateralFriction=0.8)
        shapes = [collision_shape(client, m, p) for m, p in zip(meshes, convex_parts(meshes))]
        for _ in range(MAX_LAYOUTS):
            starts = sample_layout(rng, meshes)
            bodies = [_add_body(client, s, m, T) for s, m, T in zip(shapes, meshes, starts)]
            if _settle(client, bodies) and _well_placed(client, bodies):
                # BulletClient keeps its physics client id private; the pose helper takes the id.
                return [SceneObject(n, m, get_base_pose(client._client, b)) for n, m, b in zip(names, meshes, bodies)]
            for b in bodies:
                client.removeBody(b)
    finally:
        client.disconnect()
    raise RuntimeError(f"no stable layout of {names} in {MAX_LAYOUTS} tries")


def sample_layout(rng: np.random.Generator, meshes: list[trimesh.Trimesh]) -> list[np.ndarray]:
    """Start poses ``T_world_obj`` (4x4) with random yaw and non-overlapping footprints.

    Each footprint is the circle around the mesh's x-y bounding box centre that holds all its
    vertices; circles keep ``MIN_GAP`` plus 1 cm apart (objects shift a little while settling) and lie
    inside ``SPAWN_AREA``, which grows by 10% whenever the objects do not fit.
    """
    centres = [m.bounds[:, :2].mean(axis=0) for m in meshes]
    radii = [float(np.linalg.norm(m.vertices[:, :2] - c, axis=1).max()) for m, c in zip(meshes, centres)]
    order = np.argsort(radii)[::-1]  # the largest first: they are the hardest to fit
    area = np.array(SPAWN_AREA)
    while True:
        spots = _place_circles(rng, [radii[i] for i in order], area, MIN_GAP + 0.01)
        if spots is not None:
            break
        area = area * 1.1
    starts = [np.eye(4) for _ in meshes]
    for spot, i in zip(spots, order):
        yaw = rng.uniform(-np.pi, np.pi)
        R = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
        starts[i][:2, :2] = R
        starts[i][:2, 3] = spot - R @ centres[i]  # the footprint centre lands on the spot
        starts[i][2, 3] = DROP_HEIGHT - meshes[i].bounds[0, 2]
    return starts


def _place_circles(
    rng: np.random.Generator, radii: list[float], area: np.ndarray, gap: float, tries: int = 200
) -> list[np.ndarray] | None:
    """Centres (x, y) of circles inside ``area`` (centred at the origin) at least ``gap`` apart, or None."""
    spots: list[np.ndarray] = []
    for r in radii:
        half = np.maximum(area / 2 - r, 0.0)
        for _ in range(tries):
            p = rng.uniform(-half, half)
            if all(np.linalg.norm(p - q) >= r + rq + gap for q, rq in zip(spots, radii)):
                spots.append(p)
                break
        else:
            return None
    return spots


def convex_parts(meshes: list[trimesh.Trimesh]) -> list[Path | None]:
    """V-HACD convex parts (an OBJ, object frame) of each concave mesh; None for nearly convex ones.

    pybullet gives a moving body one convex hull per mesh part. That is fine for nearly convex
    objects (boxes, cans, fruit); concave ones (mugs, bowls) would sit on their hull's lid, so they
    are decomposed (cached on disk, shared with the grasp world). Each decomposition runs in its
    own process, so threads run the uncached ones side by side.
    """

    def parts(mesh: trimesh.Trimesh) -> Path | None:
        return None if mesh.volume / mesh.convex_hull.volume >= CONVEX_ENOUGH else convex_decomposition(mesh)

    with ThreadPoolExecutor() as pool:
        return list(pool.map(parts, meshes))


def collision_shape(client: BulletClient, mesh: trimesh.Trimesh, parts: Path | None) -> int:
    """A pybullet collision shape in the mesh's object frame: the parts file, else the mesh's convex hull."""
    if parts is None:
        return client.createCollisionShape(pybullet.GEOM_MESH, vertices=np.asarray(mesh.convex_hull.vertices).tolist())
    return client.createCollisionShape(pybullet.GEOM_MESH, fileName=str(parts))


def _add_body(client: BulletClient, shape: int, mesh: trimesh.Trimesh, T_world_obj: np.ndarray) -> int:
    """A dynamic body whose link frame is the mesh frame, placed at ``T_world_obj``.

    The inertial frame sits at the mesh's centre of mass so that it tips and rests like the real
    object; :func:`~shapeviewer.grasp.hands.get_base_pose` reads the link frame back.
    """
    position, quaternion = pose_to_pq(T_world_obj)
    body = client.createMultiBody(
        baseMass=DENSITY * mesh.volume,
        baseCollisionShapeIndex=shape,
        basePosition=position,
        baseOrientation=quaternion,
        baseInertialFramePosition=mesh.center_mass.tolist(),
    )
    # A little rolling and spinning friction lets round objects come to rest.
    client.changeDynamics(body, -1, lateralFriction=0.8, rollingFriction=0.001, spinningFriction=0.001)
    return body


def _settle(client: BulletClient, bodies: list[int], lin_tol: float = 0.005, ang_tol: float = 0.05) -> bool:
    """Step until every body moves slower than ``lin_tol`` m/s and ``ang_tol`` rad/s; False if they never do."""
    for step in range(1, MAX_SETTLE_STEPS + 1):
        client.stepSimulation()
        if step % 20 == 0 and step >= 120:  # give the objects time to land first
            vel = [client.getBaseVelocity(b) for b in bodies]
            if all(np.linalg.norm(v) < lin_tol and np.linalg.norm(w) < ang_tol for v, w in vel):
                return True
    return False


def _well_placed(client: BulletClient, bodies: list[int]) -> bool:
    """Settled objects are ``MIN_GAP`` apart (on their collision shapes) and have not rolled away."""
    for i, a in enumerate(bodies):
        if np.any(np.abs(client.getBasePositionAndOrientation(a)[0][:2]) > np.array(SPAWN_AREA)):
            return False
        if any(client.getClosestPoints(a, b, MIN_GAP) for b in bodies[i + 1 :]):
            return False
    return True


# ----------------------------------------------------------------------------------------------
# The simulated Kinect


def capture_scene(
    objects: list[SceneObject],
    seed: int = 0,
    intrinsics: Intrinsics = Intrinsics.kinect(),
    noise: KinectNoise | None = KinectNoise(),
    distance: float | None = None,
) -> Capture:
    """A simulated Kinect capture of objects on the table (z = 0).

    The camera looks down at the objects' centre from ``CAMERA_ELEVATION_DEG`` below horizontal,
    ``distance`` metres away (drawn from ``CAMERA_DISTANCE`` and pushed back until every object is
    fully in the image when None). Depth and per-pixel object ids are ray cast, ``noise`` (None: an
    ideal sensor) drops and perturbs depth like a Kinect, and colours are flat object colours with
    Lambertian shading from a light above the camera.

    Returns:
        an organized (H, W, 3) camera-frame cloud with NaN at missing pixels, uint8 colours (black at
        missing pixels), ``labels`` = object index per pixel (-1 for the table, no hit or a missing
        pixel) and the camera pose ``T_world_cam``.
    """
    if not objects:
        raise ValueError("capture_scene needs at least one object to look at")
    rng = np.random.default_rng([seed, _CAMERA_STREAM])
    meshes = [
        trimesh.Trimesh(transform_points(o.T_world_obj, o.mesh.vertices), o.mesh.faces, process=False) for o in objects
    ]
    vertices = np.concatenate([m.vertices for m in meshes])
    target = (vertices.min(axis=0) + vertices.max(axis=0)) / 2
    # Geometry 0 is the table, geometry i + 1 is object i.
    renderer = RaycastRenderer([table_mesh(target), *meshes])
    T_world_cam = _choose_camera(rng, renderer, vertices, target, intrinsics, distance, len(objects))
    depth, gid, normals = renderer.render(intrinsics, T_world_cam, with_normals=True)
    if noise is not None:
        depth = noise.apply(depth, np.random.default_rng([seed, _NOISE_STREAM]))
    points = backproject(depth, intrinsics)
    valid = np.isfinite(points).all(axis=-1)
    labels = np.where(valid & (gid > 0), gid - 1, -1).astype(np.int32)
    albedo = np.concatenate([[TABLE_RGB], object_colours([o.name for o in objects])])
    colors = _shade(gid, normals, albedo, intrinsics, T_world_cam, target)
    colors[~valid] = 0
    return Capture(
        points_cam=points,
        colors=colors,
        intrinsics=intrinsics,
        T_world_cam=T_world_cam,
        source=f"default(seed={seed})",
        objects=list(objects),
        labels=labels,
    )


def default_scene(seed: int = 0) -> Capture:
    """The app's default capture: :func:`build_tabletop` seen by :func:`capture_scene`."""
    return capture_scene(build_tabletop(seed), seed=seed)


def table_mesh(centre: np.ndarray, half_size: float = TABLE_HALF_SIZE) -> trimesh.Trimesh:
    """A square of two triangles at z = 0 around ``centre`` (x, y), ``2 * half_size`` metres wide, normal up."""
    x0, y0 = centre[0] - half_size, centre[1] - half_size
    x1, y1 = centre[0] + half_size, centre[1] + half_size
    vertices = np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])
    return trimesh.Trimesh(vertices, [[0, 1, 2], [0, 2, 3]], process=False)


def _choose_camera(
    rng: np.random.Generator,
    renderer: RaycastRenderer,
    vertices: np.ndarray,
    target: np.ndarray,
    intr: Intrinsics,
    distance: float | None,
    n_objects: int,
) -> np.ndarray:
    """``T_world_cam`` of a seeded view in which every object shows at least ``MIN_VISIBLE_PX`` pixels.

    Views where a tall object hides another are re-drawn (up to ``CAMERA_TRIES``); the view whose
    least visible object shows most is kept.
    """
    best: np.ndarray | None = None
    best_px = -1
    for _ in range(CAMERA_TRIES):
        elevation = np.radians(rng.uniform(*CAMERA_ELEVATION_DEG))
        azimuth = np.radians(rng.uniform(*CAMERA_AZIMUTH_DEG))
        d = rng.uniform(*CAMERA_DISTANCE) if distance is None else distance
        direction = np.array(
            [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)]
        )
        T = look_at(target + d * direction, target)
        while distance is None and not _in_image(vertices, T, intr) and d < 3.0:
            d *= 1.05
            T = look_at(target + d * direction, target)
        _, gid = renderer.render(intr, T)
        least_px = int(np.bincount(gid.ravel() + 1, minlength=n_objects + 2)[2:].min())
        if least_px > best_px:
            best, best_px = T, least_px
        if least_px >= MIN_VISIBLE_PX:
            break
    assert best is not None  # the first try beats best_px = -1
    return best


def _in_image(points_world: np.ndarray, T_world_cam: np.ndarray, intr: Intrinsics) -> bool:
    """All points project at least ``IMAGE_MARGIN_PX`` inside the image (and lie in front of the camera)."""
    p = transform_points(np.linalg.inv(T_world_cam), points_world)
    if np.any(p[:, 2] <= 0):
        return False
    u = p[:, 0] / p[:, 2] * intr.fx + intr.cx
    v = p[:, 1] / p[:, 2] * intr.fy + intr.cy
    m = IMAGE_MARGIN_PX
    return bool(u.min() >= m and v.min() >= m and u.max() <= intr.width - 1 - m and v.max() <= intr.height - 1 - m)


def object_colours(names: list[str]) -> np.ndarray:
    """(n, 3) uint8 RGB per object, distinct from the table's and from each other's.

    Objects with a known real colour choose first (in order), keeping it unless it is too close to
    one already taken; the others get the first palette colour that is still distinct.
    """
    used = [TABLE_RGB]
    colours: dict[int, tuple] = {}
    order = sorted(range(len(names)), key=lambda i: names[i] not in YCB_RGB)  # stable: known first
    for i in order:
        choices = ([YCB_RGB[names[i]]] if names[i] in YCB_RGB else []) + list(PALETTE_RGB)
        distinct = [c for c in choices if min(np.linalg.norm(np.subtract(c, u)) for u in used) >= MIN_COLOUR_DISTANCE]
        colours[i] = distinct[0] if distinct else PALETTE_RGB[i % len(PALETTE_RGB)]
        used.append(colours[i])
    return np.array([colours[i] for i in range(len(names))], dtype=np.uint8).reshape(-1, 3)


def _shade(
    gid: np.ndarray,
    normals_world: np.ndarray,
    albedo_rgb: np.ndarray,
    intr: Intrinsics,
    T_world_cam: np.ndarray,
    target: np.ndarray,
) -> np.ndarray:
    """uint8 (H, W, 3) colours: the albedo of each pixel's geometry (``albedo_rgb[gid]``) times
    ambient plus Lambertian light; black where nothing was hit.

    The light sits above the camera (world z), so tops are bright and sides facing away darker.
    Normals are turned towards the camera because the ray caster reports them as stored.
    """
    albedo = albedo_rgb.astype(np.float32)[np.maximum(gid, 0)]
    rays = intr.pixel_directions() @ T_world_cam[:3, :3].T.astype(np.float32)
    n = np.where((np.sum(normals_world * rays, axis=-1) > 0)[..., None], -normals_world, normals_world)
    light = T_world_cam[:3, 3] - target
    light = light / np.linalg.norm(light) + np.array([0.0, 0.0, 1.0])
    lambert = np.clip(n @ (light / np.linalg.norm(light)).astype(np.float32), 0.0, 1.0)
    rgb = albedo * (AMBIENT + (1.0 - AMBIENT) * lambert[..., None])
    rgb[gid < 0] = 0.0
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
