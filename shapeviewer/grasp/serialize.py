"""Grasps to and from JSON, and a pybullet-ready scene as a zip.

JSON layout (``FORMAT``, version ``VERSION``; frame "world": the table top is z = 0, +z up;
lengths in metres, angles in radians, except the execution errors, as named in ``units``)::

    {"format": "shapeviewer.grasps", "version": 1, "frame": "world", "units": {...}, "meta": {...},
     "grasps": [{"hand": "barrett", "frame": "world",
                 "T_world_palm": 4x4 rows, "position": [x, y, z], "quaternion_xyzw": [x, y, z, w],
                 "approach": [x, y, z],
                 "dof_names": [...], "dof_values": [...], "joint_names": [...], "joint_values": [...],
                 "contacts": [{"link": ..., "position": [...], "normal": [...]}, ...],
                 "epsilon": e, "volume": v, "energy": E, "force_closure": bool,
                 "lift": null or {"success", "rise", "slip"},
                 "execution": null or {the executed state, "joint_error", "pose_error",
                                       "start_clear", "approach_contact", "lift": null or {...}},
                 "robustness": null or {"fraction", "epsilon_low", "epsilons", "lifted", "lift_rounds"}}]}

``lift`` is the planner's lift test of the grasp on the mesh it was planned on (rise and slip in
metres); ``execution.lift`` is the same test on the true object.

``robustness`` (:class:`~shapeviewer.grasp.robust.Robustness`) is how the grasp fares re-closed on
sample completions: the share of samples on which it holds, a lower quantile of its epsilon over
them (the writer may name the quantile in ``meta``), its epsilon on each sample, the share of its
lift tests that lifted the sample (null when it was not lifted on them) and how many rounds of a
lift on every sample it had. Files written before ``lift``, ``robustness`` or ``lifted`` existed
have no such key; they read as null (``lift_rounds``: one when lifted, else none).

The palm frame is the hand URDF's base link frame (origin at the centre of the palm face, +z the
approach). Reading uses ``T_world_palm``; position, quaternion, approach and force_closure are
derived copies for other tools. Floats are written with Python's shortest round-trip repr, so a
file read back gives bitwise the same values.
"""

from __future__ import annotations

import io
import json
import logging
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from shapeviewer.errors import ShapeviewerError
from shapeviewer.fileio import atomic_write
from shapeviewer.geometry import centre_of_mass
from shapeviewer.grasp.execute import ExecutionResult
from shapeviewer.grasp.hands import get_hand
from shapeviewer.grasp.plan import ProgressFn, plan
from shapeviewer.grasp.robust import Robustness
from shapeviewer.grasp.state import Grasp, GraspContact, HandState, LiftResult
from shapeviewer.grasp.world import convex_decomposition

log = logging.getLogger(__name__)

FORMAT = "shapeviewer.grasps"
VERSION = 1
UNITS = {"length": "m", "angle": "rad", "joint_error": "deg (mm for prismatic joints)", "pose_error": "mm"}


@dataclass
class GraspSet:
    """Grasps read from JSON, each with its execution and its robustness (or None), and the
    file's ``meta`` dict."""

    grasps: list[Grasp]
    executions: list[ExecutionResult | None]
    meta: dict = field(default_factory=dict)
    robustness: list[Robustness | None] = field(default_factory=list)


def _floats(a) -> list:
    return np.asarray(a, float).tolist()


def _contacts_to_list(contacts: Sequence[GraspContact]) -> list[dict]:
    return [{"link": c.link, "position": _floats(c.position), "normal": _floats(c.normal)} for c in contacts]


def _contacts_from_list(items: list[dict]) -> tuple[GraspContact, ...]:
    return tuple(GraspContact(c["link"], np.array(c["position"], float), np.array(c["normal"], float)) for c in items)


def _state_to_dict(state: HandState) -> dict:
    return {
        "hand": state.hand,
        "frame": "world",
        "T_world_palm": _floats(state.T_world_palm),
        "position": _floats(state.position),
        "quaternion_xyzw": _floats(state.quaternion_xyzw),
        "approach": _floats(state.approach),
        "dof_names": list(state.dofs),
        "dof_values": [float(v) for v in state.dofs.values()],
        "joint_names": list(state.joints),
        "joint_values": [float(v) for v in state.joints.values()],
        "contacts": _contacts_to_list(state.contacts),
        "epsilon": float(state.epsilon),
        "volume": float(state.volume),
        "force_closure": bool(state.force_closure),
    }


def _lift_to_dict(lift: LiftResult | None) -> dict | None:
    return None if lift is None else {"success": bool(lift.success), "rise": float(lift.rise), "slip": float(lift.slip)}


def _lift_from_dict(d: dict | None) -> LiftResult | None:
    return None if d is None else LiftResult(bool(d["success"]), float(d["rise"]), float(d["slip"]))


def _named(d: dict, names: str, values: str) -> dict[str, float]:
    return dict(zip(d[names], map(float, d[values])))


def grasp_to_dict(grasp: Grasp, execution: ExecutionResult | None = None, robustness: Robustness | None = None) -> dict:
    """One grasp (and its execution and robustness, if any) as a JSON-ready dict."""
    d = _state_to_dict(grasp)
    d["energy"] = float(grasp.energy)
    d["lift"] = _lift_to_dict(grasp.lift)  # the planner's lift test, on the mesh planned on
    d["execution"] = None
    if execution is not None:
        e = _state_to_dict(execution)
        e.update(
            joint_error=float(execution.joint_error),
            pose_error=float(execution.pose_error),
            start_clear=bool(execution.start_clear),
            approach_contact=bool(execution.approach_contact),
            lift=_lift_to_dict(execution.lift),
        )
        d["execution"] = e
    d["robustness"] = (
        None
        if robustness is None
        else {
            "fraction": float(robustness.fraction),
            "epsilon_low": float(robustness.epsilon_low),
            "epsilons": _floats(robustness.epsilons),
            "lifted": None if robustness.lifted is None else float(robustness.lifted),
            "lift_rounds": int(robustness.lift_rounds),
        }
    )
    return d


def _state_args(
    d: dict,
) -> tuple[str, np.ndarray, dict[str, float], dict[str, float], tuple[GraspContact, ...], float, float]:
    """The :class:`HandState` fields of a grasp's or an execution's dict, in field order."""
    return (
        d["hand"],
        np.array(d["T_world_palm"], float),
        _named(d, "dof_names", "dof_values"),
        _named(d, "joint_names", "joint_values"),
        _contacts_from_list(d["contacts"]),
        float(d["epsilon"]),
        float(d["volume"]),
    )


def grasp_from_dict(d: dict) -> tuple[Grasp, ExecutionResult | None]:
    """Inverse of :func:`grasp_to_dict`."""
    grasp = Grasp(*_state_args(d), float(d["energy"]), d.get("frame", "world"), _lift_from_dict(d.get("lift")))
    e = d.get("execution")
    if e is None:
        return grasp, None
    execution = ExecutionResult(
        *_state_args(e),
        float(e["joint_error"]),
        float(e["pose_error"]),
        bool(e["start_clear"]),
        bool(e["approach_contact"]),
        _lift_from_dict(e.get("lift")),
        e.get("frame", "world"),
    )
    return grasp, execution


def grasps_to_json(
    grasps: Sequence[Grasp],
    executions: Sequence[ExecutionResult | None] | None = None,
    meta: dict | None = None,
    robustness: Sequence[Robustness] | None = None,
) -> str:
    """The grasps (and executions and robustness scores, index-aligned; executions None where
    absent) as a JSON document, one grasp per line."""
    executions = list(executions) if executions is not None else [None] * len(grasps)
    scores: list[Robustness | None] = list(robustness) if robustness is not None else [None] * len(grasps)
    if len(executions) != len(grasps) or len(scores) != len(grasps):
        raise ValueError(f"{len(executions)} executions and {len(scores)} robustness scores for {len(grasps)} grasps")
    head = {"format": FORMAT, "version": VERSION, "frame": "world", "units": UNITS, "meta": meta or {}}
    lines = [f' "{k}": {json.dumps(v)},' for k, v in head.items()]
    items = ",\n  ".join(json.dumps(grasp_to_dict(g, e, r)) for g, e, r in zip(grasps, executions, scores))
    return "{\n" + "\n".join(lines) + '\n "grasps": [\n  ' + items + "\n ]\n}\n"


def _robustness_from_dict(d: dict) -> Robustness:
    lifted = None if d.get("lifted") is None else float(d["lifted"])
    rounds = d.get("lift_rounds", int(lifted is not None))
    return Robustness(
        float(d["fraction"]), float(d["epsilon_low"]), tuple(map(float, d["epsilons"])), lifted, int(rounds)
    )


def grasps_from_json(text: str | bytes) -> GraspSet:
    """Read a document written by :func:`grasps_to_json`."""
    doc = json.loads(text)
    if doc.get("format") != FORMAT or doc.get("version") != VERSION:
        raise ValueError(f"not a {FORMAT} v{VERSION} document: {doc.get('format')!r} v{doc.get('version')!r}")
    pairs = [grasp_from_dict(d) for d in doc["grasps"]]
    scores = [None if d.get("robustness") is None else _robustness_from_dict(d["robustness"]) for d in doc["grasps"]]
    return GraspSet([g for g, _ in pairs], [e for _, e in pairs], doc.get("meta", {}), scores)


# ---------------------------------------------------------------------------------------------
# A pybullet-ready scene.

_README = """A grasp scene exported by shapeviewer (frame "world": the table top is z = 0, +z up; metres).

object.obj            the object's mesh in the world frame (visual)
object_collision.obj  its convex decomposition (V-HACD parts: pybullet collides with each)
object.urdf           the object: visual object.obj, collision object_collision.obj, {mass} kg
hands/                the hand URDFs; a hand's base link frame is its palm frame (origin at the
                      centre of the palm face, +z the approach)
grasps.json           the grasps (palm pose, joint values, contacts, qualities; see its "units")

    import json, pybullet as p
    p.connect(p.GUI)
    p.createMultiBody(0, p.createCollisionShape(p.GEOM_PLANE))          # the table
    obj = p.loadURDF("object.urdf", useFixedBase=True)
    g = json.load(open("grasps.json"))["grasps"][0]
    hand = p.loadURDF("hands/{urdf}", g["position"], g["quaternion_xyzw"], useFixedBase=True)
    names = {{p.getJointInfo(hand, i)[1].decode(): i for i in range(p.getNumJoints(hand))}}
    for name, q in zip(g["joint_names"], g["joint_values"]):
        p.resetJointState(hand, names[name], q)
"""


def _object_urdf(mesh: trimesh.Trimesh, mass: float) -> str:
    com = centre_of_mass(mesh)
    if mesh.is_watertight and mesh.volume > 0:
        inertia = mesh.moment_inertia * (mass / mesh.mass)  # about the centre of mass, world axes
    else:
        inertia = np.diag(mass * np.sum(mesh.extents**2) / 12.0 * np.ones(3))
    (ixx, ixy, ixz), (_, iyy, iyz), (_, _, izz) = inertia
    xyz = " ".join(f"{v:.9g}" for v in com)
    return f"""<?xml version="1.0"?>
<robot name="object">
  <link name="object">
    <inertial><origin xyz="{xyz}" rpy="0 0 0"/><mass value="{mass:.9g}"/>
      <inertia ixx="{ixx:.9g}" ixy="{ixy:.9g}" ixz="{ixz:.9g}"
               iyy="{iyy:.9g}" iyz="{iyz:.9g}" izz="{izz:.9g}"/></inertial>
    <visual><geometry><mesh filename="object.obj"/></geometry></visual>
    <collision><geometry><mesh filename="object_collision.obj"/></geometry></collision>
  </link>
</robot>
"""


def scene_zip(
    mesh_world: trimesh.Trimesh,
    grasps: Sequence[Grasp],
    executions: Sequence[ExecutionResult | None] | None = None,
    meta: dict | None = None,
    mass: float = 0.2,
    robustness: Sequence[Robustness] | None = None,
) -> bytes:
    """A zip (bytes) of the object (OBJ, convex decomposition, URDF), the hands used and
    grasps.json (see :func:`grasps_to_json` for ``executions``, ``meta`` and ``robustness``),
    loadable in pybullet as its README shows. ``mesh_world``: world frame, metres."""
    hands = sorted({g.hand for g in grasps}) or ["barrett"]
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr(
            "object.obj", trimesh.exchange.obj.export_obj(mesh_world, include_normals=False, include_texture=False)
        )
        z.writestr("object_collision.obj", convex_decomposition(mesh_world).read_bytes())
        z.writestr("object.urdf", _object_urdf(mesh_world, mass))
        for name in hands:
            urdf = get_hand(name).urdf
            z.writestr(f"hands/{urdf.name}", urdf.read_bytes())
            if (urdf.parent / "LICENSE.txt").exists():  # the Panda's files come from pybullet_data
                z.writestr(f"hands/{name}_LICENSE.txt", (urdf.parent / "LICENSE.txt").read_bytes())
            # Mesh files the URDF names (the Panda's), next to it as it expects.
            for mesh_path in sorted(
                {
                    g.mesh_path
                    for geoms in get_hand(name).model.visuals.values()
                    for g in geoms
                    if g.mesh_path is not None
                }
            ):
                z.writestr(f"hands/{mesh_path.relative_to(urdf.parent).as_posix()}", mesh_path.read_bytes())
        z.writestr("grasps.json", grasps_to_json(grasps, executions, meta, robustness))
        z.writestr("README.txt", _README.format(mass=mass, urdf=get_hand(hands[0]).urdf.name))
    return buf.getvalue()


# ---------------------------------------------------------------------------------------------
# Headless use (``shapeviewer grasp MESH --hand barrett --out grasps.json``).


def plan_mesh_file(
    mesh_path: str | Path,
    out_path: str | Path,
    hand: str = "barrett",
    n_grasps: int = 20,
    seed: int = 0,
    on_table: bool = True,
    budget_seconds: float | None = None,
    progress: ProgressFn | None = None,
) -> list[Grasp]:
    """Plan grasps on the mesh file ``mesh_path`` (metres, z up) and write them to ``out_path``:
    grasps.json, or the pybullet scene when the name ends in ``.zip``.

    ``on_table``: first move the mesh up or down so that its lowest point rests on the table
    (z = 0); the shift is recorded as ``meta["T_world_mesh"]``. Returns the grasps. An open (not
    watertight) mesh is planned on with a logged warning.

    Raises:
        MeshError: the file is missing, unreadable, has no triangles (e.g. points only) or is
            flat (no volume to grasp, and V-HACD never returns on it).
        DecompositionError: V-HACD failed or was not done within the budget.
    """
    mesh = read_mesh(mesh_path)
    if not mesh.is_watertight:
        log.warning(
            "%s is not watertight (an open surface): inside and outside are guessed by ray voting, "
            "so grasp qualities are approximate",
            mesh_path,
        )
    T = np.eye(4)
    if on_table:
        T[2, 3] = -float(mesh.bounds[0, 2])
        mesh.apply_transform(T)
    grasps = plan(
        mesh, hand=hand, n_grasps=n_grasps, seed=seed, budget_seconds=budget_seconds, progress=progress
    ).grasps
    meta = {"source": str(mesh_path), "T_world_mesh": _floats(T), "hand": hand, "seed": seed}
    out_path = Path(out_path)
    data = (
        scene_zip(mesh, grasps, meta=meta) if out_path.suffix == ".zip" else grasps_to_json(grasps, meta=meta).encode()
    )
    atomic_write(out_path, data)  # a failed or interrupted run leaves no half-written file
    return grasps


class MeshError(ShapeviewerError, ValueError):
    """A mesh file that cannot be grasped; the message names the file and what is wrong with it."""


# A mesh thinner than this (m) in every direction across its main plane has no volume to grasp.
MIN_THICKNESS = 1e-3


def read_mesh(path: str | Path) -> trimesh.Trimesh:
    """A mesh file (PLY, OBJ, STL, GLB, ...; metres) as one triangle mesh, checked for grasping.

    Raises:
        MeshError: missing, unreadable, no triangles (a point cloud) or flat (thinner than
            :data:`MIN_THICKNESS`).
    """
    path = Path(path)
    if not path.is_file():
        raise MeshError(f"{path}: file not found" if not path.exists() else f"{path}: not a file")
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as e:  # trimesh raises ValueError, KeyError, IndexError... for broken files
        raise MeshError(f"{path}: not a readable mesh ({e})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise MeshError(f"{path}: no triangles (a point cloud?); grasps need a surface mesh")
    pts = np.asarray(mesh.vertices, float)
    if not np.isfinite(pts).all():
        raise MeshError(f"{path}: vertices that are not finite numbers")
    centred = pts - pts.mean(axis=0)
    thickness = float(np.ptp(centred @ np.linalg.svd(centred, full_matrices=False)[2][-1])) if len(pts) >= 3 else 0.0
    if thickness < MIN_THICKNESS:
        raise MeshError(
            f"{path}: flat ({len(mesh.faces)} triangles, {thickness * 1000:.2f} mm thick); "
            "grasps need an object with volume"
        )
    return mesh
