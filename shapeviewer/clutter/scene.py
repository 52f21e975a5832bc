"""The clutter-removal world: a pybullet client with the table, the workspace and an object set,
and the benchmark's two scene kinds, *pile* and *packed* (VGN / GIGA's ``ClutterRemovalSim``).

Frames: world, +z up; the workspace is the cube [0, WORKSPACE]^3 m and the table top is the plane
z = TABLE_Z. An object's pose is its URDF base frame in the world. Units: metres, radians, seconds.

The simulation steps at 240 Hz with 150 solver iterations and gravity on, as the benchmark's does;
objects are loaded from URDF with a global scale and keep the URDF's mass and friction.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import ShapeviewerError
from ..runtime.bullet import pybullet as p

SceneKind = Literal["pile", "packed"]
SCENES: tuple[SceneKind, ...] = ("pile", "packed")

FINGER_DEPTH = 0.05  # m: the Panda's finger depth, the benchmark's unit of size
MAX_OPENING = 0.08  # m: the Panda's widest opening
WORKSPACE = 6 * FINGER_DEPTH  # m: side of the workspace cube
TABLE_Z = FINGER_DEPTH  # m: height of the table top in the workspace
OBJECTS_PER_ROUND = 5
TIME_STEP = 1.0 / 240.0  # s
SOLVER_ITERATIONS = 150
PLANE_SCALE = 0.6  # the setup's plane.urdf (2 m square) scaled to a 1.2 m table
BOX_SCALE = 1.3  # the setup's box.urdf (20 cm square, 10 cm high) scaled around the pile
BOX_CORNER = (0.02, 0.02)  # m: where the box's corner stands on the table
BOX_SIZE = (0.26, 0.13)  # m: the scaled box's side and height (the wall box made without a setup folder)
PILE_DROP = 0.2  # m above the table where pile objects are dropped from
PILE_SCALE = (0.8, 1.0)
PACKED_SCALE = (0.7, 0.9)
PACKED_XY = (0.08, 0.22)  # m
PACKED_ATTEMPTS = 12
PACKED_GAP = 0.002  # m: a packed object is placed this far above the table, then settles
REST_TOLERANCE = 0.01  # m/s and rad/s: slower objects are at rest
REST_TIMEOUT = 2.0  # s of simulated time waited at most for objects to come to rest
DROP_REST_TIMEOUT = 1.0  # s: the wait after each pile object is dropped


class ClutterError(ShapeviewerError, ValueError):
    """Bad benchmark input: an object-set or setup folder that is missing or holds no usable URDF."""


@dataclass(frozen=True)
class ObjectSet:
    """A folder of objects, each ``NAME.urdf`` (with ``NAME_visual.obj`` / ``NAME_collision.obj``
    beside it, metres), sorted by name so that a seed draws the same objects on every machine."""

    folder: Path
    urdfs: tuple[Path, ...]

    @staticmethod
    def load(folder: str | Path) -> ObjectSet:
        """The objects of ``folder``.

        Raises:
            ClutterError: the folder does not exist or holds no ``*.urdf``.
        """
        path = Path(folder)
        if not path.is_dir():
            raise ClutterError(f"object set {path}: not a folder")
        urdfs = tuple(sorted(f for f in path.iterdir() if f.suffix == ".urdf" and f.is_file()))
        if not urdfs:
            raise ClutterError(f"object set {path}: no .urdf files in it")
        return ObjectSet(path, urdfs)

    @property
    def name(self) -> str:
        return self.folder.name


@dataclass(frozen=True)
class Setup:
    """The table and pile box: ``plane.urdf`` / ``box.urdf`` of a setup folder, or (None) pybullet's
    own plane and a box of four walls made here."""

    plane: Path | None = None
    box: Path | None = None

    @staticmethod
    def load(folder: str | Path | None) -> Setup:
        """The setup of ``folder`` (None: the built-in table and box).

        Raises:
            ClutterError: the folder is missing, or has neither ``plane.urdf`` nor ``box.urdf``.
        """
        if folder is None:
            return Setup()
        path = Path(folder)
        if not path.is_dir():
            raise ClutterError(f"setup {path}: not a folder")
        plane, box = path / "plane.urdf", path / "box.urdf"
        if not plane.is_file() and not box.is_file():
            raise ClutterError(f"setup {path}: holds neither plane.urdf nor box.urdf")
        return Setup(plane if plane.is_file() else None, box if box.is_file() else None)


@dataclass(frozen=True)
class PlacedObject:
    """An object in the world: its pybullet body, URDF and global scale."""

    body: int
    urdf: Path
    scale: float

    @property
    def name(self) -> str:
        return self.urdf.stem


class ClutterWorld:
    """A pybullet DIRECT client holding the table and the objects of one round.

    Use as a context manager (or call :meth:`close`) so that the physics client is released.
    """

    def __init__(self, setup: Setup | None = None) -> None:
        self.setup = setup or Setup()
        self.client = p.connect(p.DIRECT)
        self.objects: dict[int, PlacedObject] = {}
        self.sim_time = 0.0
        try:
            p.setPhysicsEngineParameter(
                fixedTimeStep=TIME_STEP, numSolverIterations=SOLVER_ITERATIONS, physicsClientId=self.client
            )
            p.setGravity(0.0, 0.0, -9.81, physicsClientId=self.client)
            self.table = self._load_table()
        except Exception:
            self.close()
            raise

    # -- lifetime -----------------------------------------------------------------------------

    def close(self) -> None:
        if self.client >= 0:
            p.disconnect(physicsClientId=self.client)
            self.client = -1

    def __enter__(self) -> ClutterWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- bodies -------------------------------------------------------------------------------

    def _load_table(self) -> int:
        if self.setup.plane is not None:
            urdf = str(self.setup.plane)
        else:
            import pybullet_data

            urdf = str(Path(pybullet_data.getDataPath()) / "plane.urdf")
        pos = (WORKSPACE / 2, WORKSPACE / 2, TABLE_Z)
        return p.loadURDF(urdf, pos, globalScaling=PLANE_SCALE, useFixedBase=True, physicsClientId=self.client)

    def add_box(self) -> int:
        """The open box that pile objects are dropped into (its corner at BOX_CORNER on the table)."""
        c = self.client
        if self.setup.box is not None:
            pos = (*BOX_CORNER, TABLE_Z)
            return p.loadURDF(str(self.setup.box), pos, globalScaling=BOX_SCALE, useFixedBase=True, physicsClientId=c)
        side, height = BOX_SIZE
        t = 0.01  # m: wall thickness
        lo = np.array(BOX_CORNER)
        centre = lo + side / 2
        walls = [
            ((side + t, t, height), (centre[0], lo[1], height / 2)),
            ((side + t, t, height), (centre[0], lo[1] + side, height / 2)),
            ((t, side + t, height), (lo[0], centre[1], height / 2)),
            ((t, side + t, height), (lo[0] + side, centre[1], height / 2)),
        ]
        halves = [[e / 2 for e in size] for size, _ in walls]
        offsets = [list(pos) for _, pos in walls]
        shape = p.createCollisionShapeArray(
            [p.GEOM_BOX] * 4, halfExtents=halves, collisionFramePositions=offsets, physicsClientId=c
        )
        visual = p.createVisualShapeArray(
            [p.GEOM_BOX] * 4, halfExtents=halves, visualFramePositions=offsets, physicsClientId=c
        )
        return p.createMultiBody(0.0, shape, visual, basePosition=(0.0, 0.0, TABLE_Z), physicsClientId=c)

    def add_object(self, urdf: Path, position: Sequence[float], quat_xyzw: Sequence[float], scale: float) -> int:
        """Load ``urdf`` with its base at ``position`` (world, m), orientation ``quat_xyzw``, scaled by ``scale``."""
        body = p.loadURDF(
            str(urdf),
            list(map(float, position)),
            list(map(float, quat_xyzw)),
            globalScaling=float(scale),
            physicsClientId=self.client,
        )
        self.objects[body] = PlacedObject(body, Path(urdf), float(scale))
        return body

    def remove_body(self, body: int) -> None:
        """Remove a body (an object, the box, a hand) from the world."""
        p.removeBody(body, physicsClientId=self.client)
        self.objects.pop(body, None)

    @property
    def num_objects(self) -> int:
        return len(self.objects)

    def object_position(self, body: int) -> np.ndarray:
        """The base position of a body (its centre of mass, world frame, m)."""
        return np.asarray(p.getBasePositionAndOrientation(body, physicsClientId=self.client)[0])

    def object_poses(self) -> list[dict]:
        """Every object as plain data: name, scale, position (m) and orientation (xyzw), world frame."""
        out = []
        for body, obj in sorted(self.objects.items()):
            pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=self.client)
            out.append({"name": obj.name, "scale": obj.scale, "position": list(pos), "quat_xyzw": list(quat)})
        return out

    def touching(self, body: int) -> bool:
        """Whether ``body`` touches or overlaps any other body (without stepping the simulation)."""
        c = self.client
        for other in range(p.getNumBodies(physicsClientId=c)):
            uid = p.getBodyUniqueId(other, physicsClientId=c)
            if uid != body and p.getClosestPoints(body, uid, 0.0, physicsClientId=c):
                return True
        return False

    # -- simulation ---------------------------------------------------------------------------

    def step(self, n: int = 1) -> None:
        for _ in range(n):
            p.stepSimulation(physicsClientId=self.client)
        self.sim_time += n * TIME_STEP

    def wait_for_rest(self, timeout: float = REST_TIMEOUT, tol: float = REST_TOLERANCE) -> None:
        """Simulate in quarter seconds until every object is at rest, at most ``timeout`` s of simulated time."""
        end = self.sim_time + timeout
        while self.sim_time < end:
            self.step(60)
            speeds = [np.linalg.norm(p.getBaseVelocity(body, physicsClientId=self.client)) for body in self.objects]
            if all(s <= tol for s in speeds):
                return

    def remove_outside_workspace(self) -> bool:
        """Remove the objects whose base left the workspace cube; whether any was."""
        out = [
            b
            for b in self.objects
            if np.any(self.object_position(b) < 0.0) or np.any(self.object_position(b) > WORKSPACE)
        ]
        for body in out:
            self.remove_body(body)
        return bool(out)

    def settle(self) -> None:
        """Wait for the objects to rest, removing those that left the workspace, until none does."""
        while True:
            self.wait_for_rest()
            if not self.remove_outside_workspace():
                return


def generate_pile(world: ClutterWorld, objects: ObjectSet, count: int, rng: np.random.Generator) -> None:
    """A pile: ``count`` objects drawn with replacement, each in a uniformly random orientation,
    dropped from PILE_DROP above the table at a uniform xy in the middle third of the workspace into
    the box, scaled by U(PILE_SCALE), and left to settle; then the box is removed and the pile settles."""
    box = world.add_box()
    for i in rng.integers(0, len(objects.urdfs), size=count):
        quat = Rotation.random(random_state=rng).as_quat()
        xy = rng.uniform(WORKSPACE / 3, 2 * WORKSPACE / 3, 2)
        scale = rng.uniform(*PILE_SCALE)
        world.add_object(objects.urdfs[i], (xy[0], xy[1], TABLE_Z + PILE_DROP), quat, scale)
        world.wait_for_rest(timeout=DROP_REST_TIMEOUT)
    world.remove_body(box)
    world.settle()


def generate_packed(world: ClutterWorld, objects: ObjectSet, count: int, rng: np.random.Generator) -> None:
    """Packed: up to PACKED_ATTEMPTS tries to stand one more object upright (its URDF orientation)
    at a uniform yaw and xy in PACKED_XY, scaled by U(PACKED_SCALE), its lowest point PACKED_GAP
    above the table; one touching another body is removed again, one that does not settles."""
    for _ in range(PACKED_ATTEMPTS):
        if world.num_objects >= count:
            break
        urdf = objects.urdfs[rng.integers(0, len(objects.urdfs))]
        x, y = rng.uniform(*PACKED_XY, 2)
        yaw = rng.uniform(0.0, 2.0 * np.pi)
        scale = rng.uniform(*PACKED_SCALE)
        quat = Rotation.from_rotvec([0.0, 0.0, yaw]).as_quat()
        body = world.add_object(urdf, (x, y, 1.0), quat, scale)
        lower, _ = p.getAABB(body, physicsClientId=world.client)
        base = world.object_position(body)
        base[2] += TABLE_Z + PACKED_GAP - lower[2]
        p.resetBasePositionAndOrientation(body, base.tolist(), quat, physicsClientId=world.client)
        if world.touching(body):
            world.remove_body(body)
        else:
            world.settle()


def generate_scene(
    world: ClutterWorld, scene: SceneKind, objects: ObjectSet, count: int, rng: np.random.Generator
) -> None:
    """Fill ``world`` with a ``scene`` of up to ``count`` objects drawn from ``objects`` with ``rng``."""
    if scene == "pile":
        generate_pile(world, objects, count, rng)
    elif scene == "packed":
        generate_packed(world, objects, count, rng)
    else:
        raise ClutterError(f"unknown scene {scene!r}; choose one of {', '.join(SCENES)}")
