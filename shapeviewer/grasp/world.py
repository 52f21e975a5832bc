"""A pybullet world for grasping: a table, objects, and a free-floating hand moved kinematically.

Frames: the world frame has the table top as its z = 0 plane (+z up). Object poses
``T_world_obj`` place a mesh given in its own frame; the hand is placed by its palm frame
``T_world_palm`` (see :mod:`shapeviewer.grasp.hands`). Units: metres, radians.

Nothing here steps the simulation: the hand is moved by resetting its pose and joints, and every
motion (approach, closing) is *conservative advancement*: a query of the closest distance between
the moving links and the obstacles (the table and every object) bounds how far they may move
without passing through anything, so no motion can tunnel through a thin part and a move ends
with the links between ``contact_tol / 2`` and ``contact_tol`` away from what stopped them.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from shapeviewer.errors import ShapeviewerError
from shapeviewer.geometry import centre_of_mass
from shapeviewer.grasp.hands import (
    Hand,
    HandBody,
    get_base_pose,
    load_hand,
    palm_pose,
    set_base_pose,
    set_joint_positions,
    set_joints,
    set_palm_pose,
)

from ..fileio import cache_dir
from ..runtime.bullet import pybullet as p

CONTACT_TOL = 1e-3  # a link within this distance (m) of an obstacle is in contact
# Closest-point queries look this far (m); anything farther counts as this far, which caps a
# step. Each query costs about one row per pair of convex parts (or triangles of a static
# concave mesh) within the radius, so a fine static mesh wants a smaller one.
QUERY_RADIUS = 0.03
VHACD_RESOLUTION = 100_000  # pybullet.vhacd's default is 10x slower for no gain here
MERGE_RADIUS = 5e-3  # contacts of one link closer than this (m) are one contact
MAX_PER_LINK = 2  # contacts kept per link and body: a line contact's ends; more cost epsilon time


@dataclass(frozen=True, eq=False)
class Contact:
    """A hand link touching a body.

    ``position``: the closest point on the body's surface (world frame). ``normal``: the body's
    outward unit surface normal there (world frame; the hand pushes along ``-normal``).
    ``distance``: link-to-body gap (m; negative when penetrating).
    """

    link: str
    body: int
    position: np.ndarray
    normal: np.ndarray
    distance: float


@dataclass(frozen=True, eq=False)
class CloseResult:
    """Outcome of :meth:`GraspWorld.close_fingers`.

    ``dofs``/``joints``: the hand's final dof and joint values. ``finger_blocked``: per finger,
    whether an obstacle stopped its closing short of the target (for a Barrett finger after
    breakaway: its proximal link, even if the distal then reached its limit). ``contacts``: every
    hand-object contact afterwards (table excluded). ``queries``: closest-point rounds used.
    """

    dofs: np.ndarray
    joints: np.ndarray
    finger_blocked: tuple[bool, ...]
    contacts: list[Contact]
    queries: int


@dataclass(frozen=True)
class ApproachResult:
    """Outcome of :meth:`GraspWorld.approach`: how far the palm moved (m) and whether it stopped at contact."""

    distance: float
    contact: bool


def mesh_hash(mesh: trimesh.Trimesh) -> str:
    """A key for a mesh's exact geometry (vertices and faces)."""
    h = hashlib.sha1()
    h.update(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    return h.hexdigest()


class DecompositionError(ShapeviewerError, RuntimeError):
    """V-HACD failed or did not finish in time (the message says which, for the user)."""


# V-HACD decomposes a 16k-face mesh in about a second; it never returns on some degenerate input
# (a single triangle spins forever), so every run is bounded.
VHACD_TIMEOUT = 60.0
# The cache of decompositions (a few kB to a few hundred kB each) is kept under this many bytes,
# least recently used first out; $SHAPEVIEWER_VHACD_CACHE_MB overrides.
VHACD_CACHE_BYTES = 256 * 2**20
# Temporary folders of runs that were killed (SIGKILL leaves them) are removed after this long.
_STALE_TMP_SECONDS = 2 * VHACD_TIMEOUT

# The child: bounded by its own alarm (the parent may stop waiting, e.g. a cancelled plan), so it
# can never outlive VHACD_TIMEOUT; it moves its result into the cache itself, atomically.
_VHACD_CHILD = """
import os, shutil, signal, sys
import pybullet as p
src, dst, log, final, resolution, timeout = sys.argv[1:7]
signal.alarm(max(1, int(float(timeout))))
try:
    p.vhacd(src, dst, log, resolution=int(resolution))
    if not os.path.exists(dst) or os.path.getsize(dst) == 0:
        sys.exit(3)
    os.replace(dst, final)
finally:
    shutil.rmtree(os.path.dirname(src), ignore_errors=True)
"""


def vhacd_cache_bytes() -> int:
    """The size cap of the V-HACD cache in bytes (``$SHAPEVIEWER_VHACD_CACHE_MB`` or :data:`VHACD_CACHE_BYTES`)."""
    mb = os.environ.get("SHAPEVIEWER_VHACD_CACHE_MB")
    return VHACD_CACHE_BYTES if not mb else int(float(mb) * 2**20)


def prune_vhacd_cache(folder: Path, max_bytes: int) -> list[Path]:
    """Delete the least recently used decompositions (oldest mtime; a cache hit touches its file)
    until ``folder`` holds at most ``max_bytes``, and temporary folders of killed runs; returns what
    was deleted."""
    deleted: list[Path] = []
    now = time.time()
    entries = []
    for path in folder.iterdir():
        try:
            st = path.stat()
        except FileNotFoundError:  # another process pruned it meanwhile
            continue
        if path.is_dir():
            if path.name.startswith("tmp") and now - st.st_mtime > _STALE_TMP_SECONDS:
                shutil.rmtree(path, ignore_errors=True)
                deleted.append(path)
        elif path.suffix == ".obj":
            entries.append((st.st_mtime, st.st_size, path))
    total = sum(size for _, size, _ in entries)
    for _, size, path in sorted(entries):
        if total <= max_bytes:
            break
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
            deleted.append(path)
        total -= size
    return deleted


class Decomposition:
    """A V-HACD run of one mesh in a child process, started at construction (or a cache hit).

    pybullet.vhacd holds the GIL for its whole run (a viewer's other threads would freeze) and
    prints its progress on stdout whatever the log file says: hence a child process. Use
    :meth:`wait` for the OBJ path; :meth:`cancel` (or leaving a ``with`` block early) kills the child.
    """

    def __init__(self, mesh: trimesh.Trimesh, timeout: float = VHACD_TIMEOUT):
        out_dir = cache_dir() / "vhacd"
        out_dir.mkdir(parents=True, exist_ok=True)
        self.path = out_dir / f"{mesh_hash(mesh)}_r{VHACD_RESOLUTION}.obj"
        self.timeout = timeout
        self.started = time.monotonic()
        self.process: subprocess.Popen | None = None
        if self.path.exists():
            with contextlib.suppress(FileNotFoundError):  # least recently used goes first: touch it
                os.utime(self.path)
            return
        prune_vhacd_cache(out_dir, vhacd_cache_bytes())
        tmp = Path(tempfile.mkdtemp(dir=out_dir))
        src, dst, log = tmp / "in.obj", tmp / "out.obj", tmp / "log.txt"
        mesh.export(src)
        self.process = subprocess.Popen(
            [
                sys.executable,
                "-c",
                _VHACD_CHILD,
                str(src),
                str(dst),
                str(log),
                str(self.path),
                str(VHACD_RESOLUTION),
                str(timeout),
            ],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        self._tmp = tmp

    def wait(self, timeout: float | None = None) -> Path:
        """The decomposition's OBJ, waiting at most ``timeout`` seconds (default: what is left of
        the run's own bound).

        Raises:
            DecompositionError: V-HACD failed or is not done in time (the child is then killed).
        """
        if self.process is None:
            return self.path
        left = self.timeout - (time.monotonic() - self.started)
        try:
            code = self.process.wait(timeout=max(0.0, min(left, left if timeout is None else timeout)))
        except subprocess.TimeoutExpired:
            self.cancel()
            raise DecompositionError(
                f"the convex decomposition (V-HACD) did not finish within "
                f"{min(self.timeout, timeout or self.timeout):.0f} s; the mesh may be "
                "degenerate"
            ) from None
        except BaseException:  # e.g. KeyboardInterrupt: do not leave the child behind
            self.cancel()
            raise
        if code != 0 or not self.path.exists():
            reason = "was stopped after its time limit" if code == -signal.SIGALRM else f"failed (exit code {code})"
            raise DecompositionError(f"the convex decomposition (V-HACD) {reason}; the mesh may be degenerate")
        return self.path

    def cancel(self) -> None:
        """Kill the child (if it still runs) and remove its temporary folder."""
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.process.wait(timeout=5)
        if self.process is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> Decomposition:
        return self

    def __exit__(self, *exc) -> None:
        self.cancel()


def convex_decomposition(mesh: trimesh.Trimesh, timeout: float = VHACD_TIMEOUT) -> Path:
    """An OBJ of convex parts of ``mesh`` (pybullet's V-HACD), cached under ``cache_dir()/vhacd``.

    pybullet turns a triangle mesh on a moving body into a single convex hull, so a movable
    concave object needs its parts. Decomposing a 16k-face mesh takes about a second; the cache
    is keyed by the mesh's geometry and the V-HACD settings, and files are written atomically so
    concurrent processes can share it. The cache is kept under :func:`vhacd_cache_bytes`.

    Raises:
        DecompositionError: V-HACD failed or took longer than ``timeout`` seconds.
    """
    with Decomposition(mesh, timeout) as d:
        return d.wait()


class GraspWorld:
    """A pybullet DIRECT client holding a table, objects and one hand.

    Use as a context manager (or call :meth:`close`) so that the physics client is released.
    """

    def __init__(
        self,
        hand: str | Hand = "barrett",
        *,
        table: bool = True,
        contact_tol: float = CONTACT_TOL,
        query_radius: float = QUERY_RADIUS,
    ):
        self.client = p.connect(p.DIRECT)
        self.contact_tol = contact_tol
        self.query_radius = query_radius
        self.table: int | None = None
        self.objects: list[int] = []
        if table:
            shape = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=self.client)
            self.table = p.createMultiBody(0.0, shape, physicsClientId=self.client)
        # The hand starts high above the table, out of the way of objects placed on it.
        T = np.eye(4)
        T[2, 3] = 1.0
        try:
            self.hand: HandBody = load_hand(self.client, hand, T)
        except Exception:
            self.close()
            raise

    # -- lifetime -----------------------------------------------------------------------------

    def close(self) -> None:
        if self.client >= 0:
            p.disconnect(physicsClientId=self.client)
            self.client = -1

    def __enter__(self) -> GraspWorld:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- bodies ------------------------------------------------------------------------------

    @property
    def obstacles(self) -> list[int]:
        """Bodies that stop the hand: the table (if any) and every object."""
        return ([self.table] if self.table is not None else []) + self.objects

    def add_object(
        self,
        mesh: trimesh.Trimesh,
        T_world_obj: np.ndarray | None = None,
        *,
        movable: bool = False,
        decompose: bool | None = None,
        parts: str | Path | None = None,
        mass: float = 0.2,
        friction: float = 1.0,
    ) -> int:
        """Add ``mesh`` (object frame, metres) at ``T_world_obj``; returns the pybullet body id.

        ``movable``: a dynamic body of ``mass`` kg with its centre of mass at the mesh's;
        otherwise static. ``decompose`` (default: as ``movable``): collide with the cached convex
        decomposition rather than the exact triangle mesh, which pybullet supports only for static
        bodies and which makes every closest-point query 10-100x slower (one row per nearby
        triangle), so a static object that is queried a lot should be decomposed too. ``parts``:
        an OBJ of convex parts of ``mesh`` (object frame, one ``o`` object per part, as V-HACD
        writes them) to collide with instead of the cached decomposition.
        """
        T = np.eye(4) if T_world_obj is None else np.asarray(T_world_obj, float)
        if decompose is None:
            decompose = movable
        decompose = decompose or parts is not None
        if movable and not decompose:
            raise ValueError("a movable object needs its convex decomposition")
        if decompose:
            shape = p.createCollisionShape(
                p.GEOM_MESH,
                fileName=str(convex_decomposition(mesh) if parts is None else parts),
                physicsClientId=self.client,
            )
        else:
            shape = p.createCollisionShape(
                p.GEOM_MESH,
                vertices=np.asarray(mesh.vertices, float).tolist(),
                indices=np.asarray(mesh.faces, int).ravel().tolist(),
                flags=p.GEOM_FORCE_CONCAVE_TRIMESH,
                physicsClientId=self.client,
            )
        if movable:
            body = p.createMultiBody(
                mass, shape, baseInertialFramePosition=centre_of_mass(mesh).tolist(), physicsClientId=self.client
            )
        else:
            body = p.createMultiBody(0.0, shape, physicsClientId=self.client)
        # Mesh shapes get a 1 mm collision margin by default, which would stop fingers short of
        # the surface and put contact points off it.
        p.changeDynamics(body, -1, lateralFriction=friction, collisionMargin=0.0, physicsClientId=self.client)
        set_base_pose(self.client, body, T)
        self.objects.append(body)
        return body

    def remove_object(self, body: int) -> None:
        p.removeBody(body, physicsClientId=self.client)
        self.objects.remove(body)

    def object_pose(self, body: int) -> np.ndarray:
        """``T_world_obj`` of an object added with :meth:`add_object`."""
        return get_base_pose(self.client, body)

    def set_object_pose(self, body: int, T_world_obj: np.ndarray) -> None:
        set_base_pose(self.client, body, np.asarray(T_world_obj, float))

    # -- the hand ----------------------------------------------------------------------------

    def palm_pose(self) -> np.ndarray:
        """``T_world_palm``."""
        return palm_pose(self.hand)

    def set_palm_pose(self, T_world_palm: np.ndarray) -> None:
        set_palm_pose(self.hand, T_world_palm)

    def set_dofs(self, dofs: Sequence[float]) -> None:
        """Set the hand's dofs; joints follow the coupling (see :func:`hands.set_joints`)."""
        set_joints(self.hand, dofs)

    def open_hand(self) -> None:
        """Open every finger, keeping the current spread (a preshape, not a closing dof)."""
        hand = self.hand.hand
        set_joints(self.hand, np.where(hand.closing_dofs, hand.dof_open, self.hand.dofs))

    def move_along_approach(self, distance: float) -> None:
        """Translate the palm by ``distance`` (m) along its approach axis (negative: back off)."""
        T = self.palm_pose()
        T[:3, 3] += distance * (T[:3, :3] @ np.asarray(self.hand.hand.approach, float))
        self.set_palm_pose(T)

    # -- queries -----------------------------------------------------------------------------

    def _closest(self, radius: float, bodies: Sequence[int] | None = None) -> list[tuple]:
        """Raw getClosestPoints rows between the hand and ``bodies`` (default: obstacles) within ``radius``."""
        rows = []
        for body in self.obstacles if bodies is None else bodies:
            rows += p.getClosestPoints(self.hand.body, body, radius, physicsClientId=self.client)
        return rows

    def link_gaps(self, radius: float | None = None) -> dict[int, float]:
        """Smallest distance (m) from each hand link (pybullet index) to any obstacle; links
        farther than ``radius`` (default ``query_radius``) are absent. getClosestPoints returns
        one unsorted row per pair of convex parts, so the minimum is taken here."""
        gaps: dict[int, float] = {}
        for row in self._closest(self.query_radius if radius is None else radius):
            link, d = row[3], row[8]
            if d < gaps.get(link, np.inf):
                gaps[link] = d
        return gaps

    def in_collision(self, tol: float = 0.0) -> bool:
        """Whether any hand link is within ``tol`` (m) of an obstacle (penetrating when 0)."""
        return any(d <= tol for d in self.link_gaps(max(tol, 0.0) + 1e-6).values())

    def contacts(
        self, bodies: Sequence[int] | None = None, tol: float | None = None, max_per_link: int = MAX_PER_LINK
    ) -> list[Contact]:
        """Hand contacts with ``bodies`` (default: the objects, not the table) within ``tol`` (m).

        pybullet gives one row per pair of convex parts (per triangle for a static concave mesh),
        so rows are reduced per link and body: rows closer than ``MERGE_RADIUS`` to a kept one
        are the same contact, and of the rest at most ``max_per_link`` spread-out ones are kept
        (farthest-point order from the deepest). A face contact's wrenches are spanned by the
        corners of its patch, and every extra contact multiplies the cost of the epsilon quality.
        """
        tol = self.contact_tol if tol is None else tol
        names = self.hand.link_name
        groups: dict[tuple[int, int], list[tuple]] = {}
        for row in sorted(self._closest(tol, self.objects if bodies is None else bodies), key=lambda r: r[8]):
            groups.setdefault((row[3], row[2]), []).append(row)
        out: list[Contact] = []
        for (link, body), rows in groups.items():
            kept = [rows[0]]
            rest = rows[1:]
            while rest and len(kept) < max_per_link:
                spread = [min(np.linalg.norm(np.subtract(r[6], k[6])) for k in kept) for r in rest]
                i = int(np.argmax(spread))
                if spread[i] < MERGE_RADIUS:
                    break
                kept.append(rest.pop(i))
            out += [Contact(names[link], body, np.asarray(r[6]), np.asarray(r[7]), float(r[8])) for r in kept]
        return out

    # -- motions -----------------------------------------------------------------------------

    def approach(self, max_distance: float = 0.2, max_queries: int = 500) -> ApproachResult:
        """Move the palm along its approach axis until any hand link touches an obstacle
        (within ``contact_tol``) or it has moved ``max_distance`` (m).

        A translation moves every point of the hand by the same amount, so each step is the
        current clearance minus ``contact_tol / 2``; this takes a few queries instead of one per
        millimetre.
        """
        tol = self.contact_tol
        moved = 0.0
        for _ in range(max_queries):
            gaps = self.link_gaps()
            gap = min(gaps.values(), default=self.query_radius)
            if gap <= tol:
                return ApproachResult(moved, True)
            if moved >= max_distance:
                break
            step = min(gap - tol / 2, max_distance - moved)
            self.move_along_approach(step)
            moved += step
        return ApproachResult(moved, False)

    def close_fingers(self, target: Sequence[float] | None = None, max_queries: int = 400) -> CloseResult:
        """Close every finger from its current value towards ``target`` dofs (default: the
        hand's closed values; dofs that closing does not move, like the spread, are ignored, and
        a finger already at or past its target stays where it is).

        All fingers move together, each by its own safe step, with one closest-point query round
        per step. A finger stops when one of its links touches an obstacle, except the Barrett
        breakaway: when only the proximal link is blocked, the distal joint keeps closing alone
        (its dof advancing with it, 1:1) until the distal link touches or reaches its limit.
        """
        hb = self.hand
        hand = hb.hand
        tol = self.contact_tol
        goal = hand.clip_dofs(hand.dof_closed if target is None else target)
        dofs, joints = hb.dofs.copy(), hb.joints.copy()
        lower, upper = hand.joint_limits
        joint_pos = {n: i for i, n in enumerate(hand.joint_names)}
        coupled = {
            f.name: [(joint_pos[c.joint], c.gain) for c in hand.coupling if c.dof == f.dof] for f in hand.fingers
        }
        phase = {f.name: "coupled" for f in hand.fingers}
        blocked = {f.name: False for f in hand.fingers}
        for f in hand.fingers:
            # Only closing: a finger already at or past its target (towards closed) stays put.
            closing = np.sign(hand.dof_closed[f.dof] - hand.dof_open[f.dof])
            if closing * (goal[f.dof] - dofs[f.dof]) <= 1e-12:
                phase[f.name] = "done"
        queries = 0
        while queries < max_queries and any(ph != "done" for ph in phase.values()):
            gaps = self.link_gaps()
            queries += 1
            for f in hand.fingers:
                if phase[f.name] == "done":
                    continue
                remaining = goal[f.dof] - dofs[f.dof]
                sign = np.sign(remaining)
                if phase[f.name] == "coupled":
                    touching = [n for n in f.links if gaps.get(hb.link_index[n], np.inf) <= tol]
                    if touching and f.breakaway_joint and not set(touching) & set(f.breakaway_links):
                        phase[f.name], blocked[f.name] = "breakaway", True
                    elif touching:
                        phase[f.name], blocked[f.name] = "done", True
                        continue
                    else:
                        gap = min(gaps.get(hb.link_index[n], self.query_radius) for n in f.links)
                        step = min((gap - tol / 2) / hand.lever(f), abs(remaining))
                        dofs[f.dof] += sign * step
                        for j, gain in coupled[f.name]:
                            joints[j] = np.clip(joints[j] + gain * sign * step, lower[j], upper[j])
                        if step >= abs(remaining):
                            phase[f.name] = "done"
                        continue
                # Breakaway: only the distal joint moves, towards closing (+).
                assert f.breakaway_joint is not None  # the phase is only entered for a breakaway finger
                j = joint_pos[f.breakaway_joint]
                if any(gaps.get(hb.link_index[n], np.inf) <= tol for n in f.breakaway_links):
                    phase[f.name], blocked[f.name] = "done", True
                    continue
                gap = min(gaps.get(hb.link_index[n], self.query_radius) for n in f.breakaway_links)
                room = min(upper[j] - joints[j], abs(remaining))
                step = min((gap - tol / 2) / hand.lever(f, breakaway=True), room)
                joints[j] += step
                dofs[f.dof] += sign * step
                if step >= room:
                    phase[f.name] = "done"
            set_joint_positions(hb, joints)
        hb.dofs = dofs
        return CloseResult(
            dofs.copy(), hb.joints.copy(), tuple(blocked[f.name] for f in hand.fingers), self.contacts(), queries
        )
