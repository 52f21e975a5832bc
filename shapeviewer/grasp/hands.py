"""Hand descriptions, forward kinematics, visual meshes, and loading a hand into pybullet.

Frames: every hand's URDF base frame is its *palm frame*: origin at the centre of the palm face,
+z the approach direction out of the palm. Poses are 4x4 homogeneous matrices; ``T_a_b`` maps
coordinates in frame b to frame a. Units: metres and radians.

Two kinds of joint vector are used:
- *dofs*: the actuated values, ``hand.dof_names`` (Barrett: spread, f1, f2, f3; Panda: left and
  right finger openings);
- *joints*: every movable URDF joint, ``hand.joint_names``. ``hand.joints_from_dofs`` applies the
  coupling (Barrett: both spread joints follow the spread; proximal = q, distal = q/3 + 42 deg).
  After a Barrett breakaway the distal joint is ahead of its coupled value, so the joints are the
  full state and the dofs alone do not determine them.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cache, cached_property
from pathlib import Path

import numpy as np
import numpy.typing as npt
import trimesh
from scipy.spatial.transform import Rotation

from shapeviewer.geometry import concatenate_meshes, pose_to_pq, pq_to_pose

from ..runtime.bullet import pybullet as p

HANDS_DIR = Path(__file__).resolve().parents[2] / "static_assets" / "hands"
HAND_NAMES = ("barrett", "panda")


# ---------------------------------------------------------------------------------------------
# A minimal URDF reader: enough for forward kinematics and drawing, independent of pybullet.


@cache
def _mesh_file(path: Path) -> trimesh.Trimesh:
    """A mesh file, read once per process (callers copy it before changing it)."""
    return trimesh.load_mesh(path, process=False)


@dataclass(frozen=True, eq=False)
class Geometry:
    """One visual or collision element of a link, in the link frame (``T_link_geom``).

    ``size``: box (x, y, z) full extents; cylinder and capsule (radius, length along z);
    sphere (radius,); mesh: the scale (sx, sy, sz) applied to ``mesh_path``.
    """

    kind: str
    T_link_geom: np.ndarray
    size: tuple[float, ...]
    mesh_path: Path | None = None
    rgba: tuple[float, float, float, float] | None = None

    def sample_points(self) -> np.ndarray:
        """Points (N x 3, link frame) whose motion bounds the motion of the whole element."""
        if self.kind == "box":
            half = np.asarray(self.size) / 2.0
            local = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
        elif self.kind in ("cylinder", "capsule"):
            r, length = self.size
            a = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
            ring = np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(a)], axis=1)
            ends = (-length / 2, length / 2) if self.kind == "cylinder" else (-length / 2 - r, length / 2 + r)
            local = np.vstack([ring + [0, 0, ends[0]], ring + [0, 0, ends[1]]])
        elif self.kind == "sphere":
            local = np.vstack([np.eye(3), -np.eye(3)]) * self.size[0]
        else:
            local = np.asarray(self.mesh().vertices)
        return local @ self.T_link_geom[:3, :3].T + self.T_link_geom[:3, 3]

    def mesh(self) -> trimesh.Trimesh:
        """The element as a triangle mesh in its own geometry frame (not yet moved by ``T_link_geom``)."""
        if self.kind == "box":
            m = trimesh.creation.box(extents=self.size)
        elif self.kind == "cylinder":
            m = trimesh.creation.cylinder(radius=self.size[0], height=self.size[1], sections=32)
        elif self.kind == "capsule":
            m = trimesh.creation.capsule(height=self.size[1], radius=self.size[0])
        elif self.kind == "sphere":
            m = trimesh.creation.icosphere(subdivisions=2, radius=self.size[0])
        else:
            m = _mesh_file(self.mesh_path).copy()
            m.apply_scale(self.size)
        if self.rgba is not None:
            m.visual.face_colors = (np.asarray(self.rgba) * 255).astype(np.uint8)
        return m


@dataclass(frozen=True, eq=False)
class UrdfJoint:
    """A URDF joint: the child frame is ``T_parent_joint @ motion(q)`` in the parent frame."""

    name: str
    kind: str  # revolute | continuous | prismatic | fixed
    parent: str
    child: str
    T_parent_joint: np.ndarray
    axis: np.ndarray
    lower: float
    upper: float

    def motion(self, q: float) -> np.ndarray:
        """The joint's own transform at value ``q`` (rad or m)."""
        T = np.eye(4)
        if self.kind in ("revolute", "continuous"):
            T[:3, :3] = _axis_angle_matrix(self.axis, q)
        elif self.kind == "prismatic":
            T[:3, 3] = self.axis * q
        return T


def _axis_angle_matrix(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation by ``angle`` (rad) about unit ``axis`` (Rodrigues; scipy's Rotation costs about a
    millisecond per call, and forward kinematics runs in every planning and execution step)."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def _attr(elem: ET.Element, key: str) -> str:
    """A required attribute of a URDF element."""
    value = elem.get(key)
    if value is None:
        raise ValueError(f"URDF <{elem.tag}> without the {key!r} attribute")
    return value


def _child(elem: ET.Element, tag: str) -> ET.Element:
    """A required child element of a URDF element."""
    child = elem.find(tag)
    if child is None:
        raise ValueError(f"URDF <{elem.tag}> without a <{tag}>")
    return child


def _rgba(text: str) -> tuple[float, float, float, float]:
    r, g, b, a = (float(v) for v in text.split())
    return r, g, b, a


def _origin(elem: ET.Element | None) -> np.ndarray:
    T = np.eye(4)
    if elem is not None:
        T[:3, 3] = [float(v) for v in elem.get("xyz", "0 0 0").split()]
        # URDF rpy is extrinsic x-y-z (R = Rz(yaw) Ry(pitch) Rx(roll)).
        T[:3, :3] = Rotation.from_euler("xyz", [float(v) for v in elem.get("rpy", "0 0 0").split()]).as_matrix()
    return T


@dataclass(frozen=True, eq=False)
class UrdfModel:
    """Links, their geometry and the joint tree of a URDF file."""

    path: Path
    root: str
    visuals: Mapping[str, tuple[Geometry, ...]]
    collisions: Mapping[str, tuple[Geometry, ...]]
    joints: tuple[UrdfJoint, ...]  # parents before children

    @staticmethod
    def load(path: Path) -> UrdfModel:
        robot = ET.parse(path).getroot()
        colours = {
            _attr(m, "name"): _rgba(_attr(_child(m, "color"), "rgba"))
            for m in robot.findall("material")
            if m.find("color") is not None
        }

        def geometries(link: ET.Element, tag: str) -> tuple[Geometry, ...]:
            out = []
            for el in link.findall(tag):
                g = _child(el, "geometry")[0]
                mat = el.find("material")
                rgba = colours.get(_attr(mat, "name")) if mat is not None else None
                size: tuple[float, ...]
                if g.tag == "box":
                    size = tuple(float(v) for v in _attr(g, "size").split())
                elif g.tag in ("cylinder", "capsule"):
                    size = (float(_attr(g, "radius")), float(_attr(g, "length")))
                elif g.tag == "sphere":
                    size = (float(_attr(g, "radius")),)
                else:
                    size = tuple(float(v) for v in g.get("scale", "1 1 1").split())
                mesh_path = path.parent / _attr(g, "filename") if g.tag == "mesh" else None
                out.append(Geometry(g.tag, _origin(el.find("origin")), size, mesh_path, rgba))
            return tuple(out)

        links = robot.findall("link")
        visuals = {_attr(link, "name"): geometries(link, "visual") for link in links}
        collisions = {_attr(link, "name"): geometries(link, "collision") for link in links}
        by_parent: dict[str, list[UrdfJoint]] = {}
        children = set()
        for j in robot.findall("joint"):
            limit = j.find("limit")
            axis = j.find("axis")
            joint = UrdfJoint(
                name=_attr(j, "name"),
                kind=_attr(j, "type"),
                parent=_attr(_child(j, "parent"), "link"),
                child=_attr(_child(j, "child"), "link"),
                T_parent_joint=_origin(j.find("origin")),
                axis=np.array([float(v) for v in (_attr(axis, "xyz") if axis is not None else "1 0 0").split()]),
                lower=float(limit.get("lower", "-inf")) if limit is not None else -math.inf,
                upper=float(limit.get("upper", "inf")) if limit is not None else math.inf,
            )
            by_parent.setdefault(joint.parent, []).append(joint)
            children.add(joint.child)
        root = next(_attr(link, "name") for link in links if _attr(link, "name") not in children)
        ordered: list[UrdfJoint] = []
        stack = [root]
        while stack:
            for joint in by_parent.get(stack.pop(), []):
                ordered.append(joint)
                stack.append(joint.child)
        return UrdfModel(path, root, visuals, collisions, tuple(ordered))

    def link_poses(self, joint_values: Mapping[str, float]) -> dict[str, np.ndarray]:
        """``T_root_link`` for every link; joints missing from ``joint_values`` are at 0."""
        poses = {self.root: np.eye(4)}
        for j in self.joints:
            poses[j.child] = poses[j.parent] @ j.T_parent_joint @ j.motion(joint_values.get(j.name, 0.0))
        return poses


# ---------------------------------------------------------------------------------------------
# Hand descriptions.


@dataclass(frozen=True)
class JointCoupling:
    """URDF joint ``joint`` = clip(gain * dofs[dof] + offset) to the joint's limits."""

    joint: str
    dof: int
    gain: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class Finger:
    """A finger closed by one dof.

    ``links``: collision links its dof moves (proximal first). A contact on any of them stops the
    finger, except that when only links before ``breakaway_joint`` are blocked (the Barrett's
    proximal link) the breakaway joint keeps closing alone, moving ``breakaway_links``, until they
    touch too or the joint reaches its limit.
    """

    name: str
    dof: int
    links: tuple[str, ...]
    breakaway_joint: str | None = None
    breakaway_links: tuple[str, ...] = ()


@dataclass(frozen=True)
class VirtualContact:
    """A preset contact point of the hand (GraspIt's "virtual contacts"), in its link's frame.

    ``normal`` is the outward unit normal of the hand surface there (pointing at a grasped object).
    A planner can score a pose by how well these points meet the object surface before closing.
    """

    link: str
    point: tuple[float, float, float]
    normal: tuple[float, float, float]


@dataclass(frozen=True, eq=False)
class Hand:
    """A hand: its URDF, actuated dofs, coupling to URDF joints, fingers and approach axis.

    ``dof_open``/``dof_closed``: where each dof is when open and where closing drives it (a dof
    with equal values, like the Barrett spread, is not moved by closing). ``approach``: the
    approach direction in the palm frame (always +z here).
    """

    name: str
    urdf: Path
    dof_names: tuple[str, ...]
    dof_lower: tuple[float, ...]
    dof_upper: tuple[float, ...]
    dof_open: tuple[float, ...]
    dof_closed: tuple[float, ...]
    coupling: tuple[JointCoupling, ...]
    fingers: tuple[Finger, ...]
    virtual_contacts: tuple[VirtualContact, ...] = ()
    approach: tuple[float, float, float] = (0.0, 0.0, 1.0)
    palm_link: str = "palm"
    _lever_cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @cached_property
    def model(self) -> UrdfModel:
        return UrdfModel.load(self.urdf)

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Movable URDF joints, in the order of every joints vector."""
        return tuple(c.joint for c in self.coupling)

    @cached_property
    def joint_limits(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) of the joints in ``joint_names`` order, from the URDF."""
        by_name = {j.name: j for j in self.model.joints}
        return (
            np.array([by_name[n].lower for n in self.joint_names]),
            np.array([by_name[n].upper for n in self.joint_names]),
        )

    @property
    def closing_dofs(self) -> np.ndarray:
        """Bool mask over ``dof_names``: the dofs that closing moves (open and closed differ); the
        others, like the Barrett spread, are the preshape."""
        return np.not_equal(self.dof_open, self.dof_closed)

    @property
    def closing_joints(self) -> np.ndarray:
        """Bool mask over ``joint_names``: the joints that a closing dof drives (the fingers)."""
        closing = self.closing_dofs
        return np.array([bool(closing[c.dof]) for c in self.coupling])

    def clip_dofs(self, dofs: npt.ArrayLike) -> np.ndarray:
        return np.clip(np.asarray(dofs, float), self.dof_lower, self.dof_upper)

    def clip_joints(self, joints: npt.ArrayLike) -> np.ndarray:
        lower, upper = self.joint_limits
        return np.clip(np.asarray(joints, float), lower, upper)

    def joints_from_dofs(self, dofs: npt.ArrayLike) -> np.ndarray:
        """Joint values implied by the coupling (no breakaway), clipped to the joint limits."""
        d = self.clip_dofs(dofs)
        return self.clip_joints([c.gain * d[c.dof] + c.offset for c in self.coupling])

    def link_poses(self, joints: npt.ArrayLike) -> dict[str, np.ndarray]:
        """``T_palm_link`` of every link at ``joints``."""
        return self.model.link_poses(dict(zip(self.joint_names, np.asarray(joints, float))))

    def virtual_contacts_palm(self, joints: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Virtual contact points and outward normals (each K x 3) in the palm frame at ``joints``."""
        poses = self.link_poses(joints)
        pts = np.array([poses[v.link][:3, :3] @ v.point + poses[v.link][:3, 3] for v in self.virtual_contacts])
        nrm = np.array([poses[v.link][:3, :3] @ v.normal for v in self.virtual_contacts])
        return pts.reshape(-1, 3), nrm.reshape(-1, 3)

    def lever(self, finger: Finger, breakaway: bool = False) -> float:
        """Upper bound (m per unit dof) on how fast any point of the finger moves as it closes.

        With it, closing by ``gap / lever`` can never make the finger pass through anything that
        is ``gap`` away (conservative advancement). ``breakaway``: for the breakaway joint alone.
        Computed numerically from the collision geometry over the whole dof range.
        """
        key = (finger.name, breakaway)
        if key not in self._lever_cache:
            self._lever_cache[key] = self._compute_lever(finger, breakaway)
        return self._lever_cache[key]

    def _compute_lever(self, finger: Finger, breakaway: bool) -> float:
        links = finger.breakaway_links if breakaway else finger.links
        points = {name: np.vstack([g.sample_points() for g in self.model.collisions[name]]) for name in links}
        names = self.joint_names
        lower, upper = self.joint_limits
        h = 1e-4

        def world_points(joints: np.ndarray) -> np.ndarray:
            poses = self.link_poses(joints)
            return np.vstack([pts @ poses[n][:3, :3].T + poses[n][:3, 3] for n, pts in points.items()])

        def speed_at(joints: np.ndarray, moved: np.ndarray) -> float:
            return float(np.max(np.linalg.norm(world_points(moved) - world_points(joints), axis=1))) / h

        speed = 0.0
        if breakaway:
            j = names.index(finger.breakaway_joint)
            for q in np.linspace(lower[j], upper[j] - h, 12):
                joints = self.joints_from_dofs(self.dof_open)
                joints[j] = q
                moved = joints.copy()
                moved[j] += h
                speed = max(speed, speed_at(joints, moved))
        else:
            lo, hi = sorted((self.dof_open[finger.dof], self.dof_closed[finger.dof]))
            for q in np.linspace(lo, hi - h, 15):
                dofs = np.array(self.dof_open, float)
                dofs[finger.dof] = q
                moved = dofs.copy()
                moved[finger.dof] += h
                speed = max(speed, speed_at(self.joints_from_dofs(dofs), self.joints_from_dofs(moved)))
        # Margin for the sampling between grid values.
        return 1.2 * speed


def _barrett() -> Hand:
    finger_max = math.radians(140.0)
    distal_offset = math.radians(42.0)
    coupling = []
    for f, dof in (("f1", 1), ("f2", 2), ("f3", 3)):
        if f != "f3":
            coupling.append(JointCoupling(f"{f}_spread", 0))
        coupling += [JointCoupling(f"{f}_proximal", dof), JointCoupling(f"{f}_distal", dof, 1.0 / 3.0, distal_offset)]
    fingers = tuple(
        Finger(f, dof, (f"{f}_proximal", f"{f}_distal"), f"{f}_distal", (f"{f}_distal",))
        for f, dof in (("f1", 1), ("f2", 2), ("f3", 3))
    )
    # Inner faces: the finger frame's +x points at the palm axis; proximal links are 20 mm thick,
    # distal links 18 mm (tools/make_barrett_urdf.py).
    contacts = [VirtualContact("palm", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))]
    for f in ("f1", "f2", "f3"):
        contacts += [
            VirtualContact(f"{f}_proximal", (0.010, 0.0, 0.045), (1.0, 0.0, 0.0)),
            VirtualContact(f"{f}_distal", (0.009, 0.0, 0.030), (1.0, 0.0, 0.0)),
        ]
    return Hand(
        name="barrett",
        urdf=HANDS_DIR / "barrett_bh8_280.urdf",
        dof_names=("spread", "f1", "f2", "f3"),
        dof_lower=(0.0, 0.0, 0.0, 0.0),
        dof_upper=(math.pi, finger_max, finger_max, finger_max),
        dof_open=(0.0, 0.0, 0.0, 0.0),
        dof_closed=(0.0, finger_max, finger_max, finger_max),
        coupling=tuple(coupling),
        fingers=fingers,
        virtual_contacts=tuple(contacts),
    )


def _panda() -> Hand:
    # Finger pads: the inner face is the link frame's y = 0 plane, facing the other finger.
    contacts = (
        VirtualContact("palm", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
        VirtualContact("left_finger", (0.0, 0.0, 0.040), (0.0, -1.0, 0.0)),
        VirtualContact("right_finger", (0.0, 0.0, 0.040), (0.0, 1.0, 0.0)),
    )
    return Hand(
        name="panda",
        urdf=HANDS_DIR / "panda" / "panda_hand.urdf",
        dof_names=("left", "right"),
        dof_lower=(0.0, 0.0),
        dof_upper=(0.04, 0.04),
        dof_open=(0.04, 0.04),
        dof_closed=(0.0, 0.0),
        coupling=(JointCoupling("left_finger_joint", 0), JointCoupling("right_finger_joint", 1)),
        fingers=(Finger("left", 0, ("left_finger",)), Finger("right", 1, ("right_finger",))),
        virtual_contacts=contacts,
    )


@cache
def get_hand(name: str) -> Hand:
    """The hand called ``name`` (one of :data:`HAND_NAMES`)."""
    builders = {"barrett": _barrett, "panda": _panda}
    if name not in builders:
        raise ValueError(f"unknown hand {name!r}; known: {', '.join(HAND_NAMES)}")
    return builders[name]()


# ---------------------------------------------------------------------------------------------
# Meshes for drawing.


def hand_meshes(hand: Hand, joints: npt.ArrayLike) -> list[tuple[trimesh.Trimesh, np.ndarray]]:
    """Visual elements of the hand at ``joints``: (mesh in its own frame, ``T_palm_mesh``) pairs.

    Meshes are fresh copies, coloured from the URDF materials; safe to modify.
    """
    poses = hand.link_poses(joints)
    return [(g.mesh(), poses[link] @ g.T_link_geom) for link, geoms in hand.model.visuals.items() for g in geoms]


def hand_mesh(hand: Hand, joints: npt.ArrayLike) -> trimesh.Trimesh:
    """The whole hand at ``joints`` as one coloured mesh in the palm frame."""
    parts = []
    for mesh, T in hand_meshes(hand, joints):
        mesh.apply_transform(T)
        parts.append(mesh)
    return concatenate_meshes(parts)


# ---------------------------------------------------------------------------------------------
# pybullet.


def _T_link_inertial(client: int, body: int) -> np.ndarray:
    info = p.getDynamicsInfo(body, -1, physicsClientId=client)
    return pq_to_pose(info[3], info[4])


def get_base_pose(client: int, body: int) -> np.ndarray:
    """``T_world_base`` of a body's base *link frame*.

    pybullet's get/resetBasePositionAndOrientation work on the base's inertial frame, which
    differs from the link frame whenever the centre of mass is off the link origin.
    """
    T_world_inertial = pq_to_pose(*p.getBasePositionAndOrientation(body, physicsClientId=client))
    return T_world_inertial @ np.linalg.inv(_T_link_inertial(client, body))


def set_base_pose(client: int, body: int, T_world_base: np.ndarray) -> None:
    """Place a body so that its base *link frame* is at ``T_world_base`` (see :func:`get_base_pose`)."""
    pos, quat = pose_to_pq(T_world_base @ _T_link_inertial(client, body))
    p.resetBasePositionAndOrientation(body, pos, quat, physicsClientId=client)


@dataclass(eq=False)
class HandBody:
    """A hand loaded into a pybullet client, with its current dofs and joints (kept in sync).

    ``link_index``: pybullet link index of each URDF link (the palm is -1).
    """

    hand: Hand
    client: int
    body: int
    link_index: dict[str, int]
    joint_index: tuple[int, ...]  # pybullet joint index per hand.joint_names
    dofs: np.ndarray
    joints: np.ndarray

    @property
    def link_name(self) -> dict[int, str]:
        return {i: n for n, i in self.link_index.items()}


def load_hand(client: int, name: str | Hand, T_world_palm: np.ndarray | None = None) -> HandBody:
    """Load a hand into ``client`` with its palm frame at ``T_world_palm`` (identity by default), open.

    The base is free (not fixed) so that a later dynamic test can move it with a constraint; the
    kinematic world never steps the simulation, so the hand stays where it is put.
    """
    hand = get_hand(name) if isinstance(name, str) else name
    T = np.eye(4) if T_world_palm is None else np.asarray(T_world_palm, float)
    pos, quat = pose_to_pq(T)
    body = p.loadURDF(
        str(hand.urdf), pos, quat, useFixedBase=False, flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client
    )
    link_index = {p.getBodyInfo(body, physicsClientId=client)[0].decode(): -1}
    joint_by_name = {}
    for i in range(p.getNumJoints(body, physicsClientId=client)):
        info = p.getJointInfo(body, i, physicsClientId=client)
        joint_by_name[info[1].decode()] = i
        link_index[info[12].decode()] = i
    hb = HandBody(
        hand,
        client,
        body,
        link_index,
        tuple(joint_by_name[n] for n in hand.joint_names),
        np.array(hand.dof_open, float),
        hand.joints_from_dofs(hand.dof_open),
    )
    set_base_pose(client, body, T)
    set_joints(hb, hand.dof_open)
    return hb


def set_joint_positions(hb: HandBody, joints: npt.ArrayLike) -> None:
    """Set every movable joint (``hand.joint_names`` order), clipped to its limits; dofs untouched."""
    hb.joints = hb.hand.clip_joints(joints)
    p.resetJointStatesMultiDof(
        hb.body, list(hb.joint_index), [[float(q)] for q in hb.joints], physicsClientId=hb.client
    )


def set_joints(hb: HandBody, dofs: npt.ArrayLike) -> None:
    """Set the hand's dofs (clipped to their limits) and every joint through the coupling."""
    hb.dofs = hb.hand.clip_dofs(dofs)
    set_joint_positions(hb, hb.hand.joints_from_dofs(hb.dofs))


def palm_pose(hb: HandBody) -> np.ndarray:
    """``T_world_palm``."""
    return get_base_pose(hb.client, hb.body)


def set_palm_pose(hb: HandBody, T_world_palm: np.ndarray) -> None:
    set_base_pose(hb.client, hb.body, np.asarray(T_world_palm, float))
