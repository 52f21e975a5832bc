"""The grasps' scene nodes (layer ``grasps``), in the viewer's WORLD frame (metres, z up).

- ``/grasps/seg_<id>``: one frame per segment with grasps;
- ``/grasps/seg_<id>/g<k>``: a frame at grasp k's ``T_world_palm``, its children ``hand/palm`` and
  ``hand/fingers`` (the palm link and every other link, each one mesh in the palm frame) and
  ``skeleton`` its stick figure, coloured by epsilon (:func:`epsilon_colors`);
- ``/grasps/seg_<id>/truth``: the true object, translucent, once a grasp was executed on it;
- ``/grasps/seg_<id>/exec_g<k>``: the hand as executed on the true object (blue, translucent).

The selected grasp shows as a solid hand, the others as stick figures: twenty of them show where
the grasps are without hiding the object the way twenty solid (or translucent) hands do.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import viser

from ...grasp.hands import Hand, get_hand
from ...perception.camera import transform_points
from ..audience import Audience
from ..rays import first_hit, sample_segments
from ..visuals import shade
from .state import SegmentGrasps

NO_CLOSURE_COLOR = (150, 150, 150)  # grasps without force closure (epsilon <= 0)
EPSILON_STOPS = (0.0, 0.5, 1.0)  # epsilon / the best epsilon ...
EPSILON_COLORS = ((215, 40, 30), (235, 160, 0), (20, 160, 60))  # ... red, amber, green
EXECUTED_COLOR = (40, 110, 235)
EXECUTED_OPACITY = 0.6
TRUTH_COLOR = (250, 200, 60)  # gold: unlike any segment colour
TRUTH_OPACITY = 0.5
SKELETON_THICKNESS = 0.003  # m: the stick figures of the grasps other than the selected one
# A click picks a hand when its ray passes within PICK_TOLERANCE (+ 1 % of the distance) of a
# point along the hand's stick figure; nearer than a segment's tolerance, since hands crowd.
PICK_SPACING = 0.004  # m between those points
PICK_TOLERANCE = 0.006  # m
PALM_SHADE = 0.7  # the palm a little darker than the fingers, so the hand's shape reads at a glance


def epsilon_colors(epsilons: Sequence[float]) -> list[tuple[int, int, int]]:
    """RGB of each grasp by its epsilon: red (near 0) through amber to green (the best of
    ``epsilons``); grey without force closure (epsilon <= 0). Relative to the best so that one
    object's grasps spread over the whole scale whatever its size. (Saturated stops, not
    matplotlib's RdYlGn, whose pale middle vanishes against the light table.)"""
    eps = np.asarray(epsilons, dtype=np.float64)
    best = float(eps.max()) if len(eps) and eps.max() > 0 else 1.0
    x = np.clip(eps / best, 0.0, 1.0)
    rgb = np.stack([np.interp(x, EPSILON_STOPS, [c[i] for c in EPSILON_COLORS]) for i in range(3)], axis=-1)
    return [NO_CLOSURE_COLOR if e <= 0 else _rounded_rgb(c) for e, c in zip(eps, rgb)]


def _rounded_rgb(c: np.ndarray) -> tuple[int, int, int]:
    r, g, b = (int(round(v)) for v in c)
    return r, g, b


@functools.cache
def _visual_parts(hand_name: str) -> tuple[tuple[str, np.ndarray, np.ndarray], ...]:
    """The hand's visual elements as ``(link, vertices in the link frame (m), faces)``, made once."""
    hand = get_hand(hand_name)
    parts = []
    for link, geoms in hand.model.visuals.items():
        for g in geoms:
            m = g.mesh()
            parts.append((link, transform_points(g.T_link_geom, m.vertices), np.asarray(m.faces, np.uint32)))
    return tuple(parts)


def hand_solids(hand: Hand, joints: Sequence[float]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The hand at ``joints`` as two meshes, ``"palm"`` (its palm link) and ``"fingers"`` (every
    other link): ``(vertices (N, 3) float32 in the palm frame (m), faces (M, 3) uint32)``.
    Two meshes instead of one per link: drawing twenty hands stays a few scene messages each."""
    poses = hand.link_poses(joints)
    groups: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {"palm": ([], []), "fingers": ([], [])}
    for link, vertices, faces in _visual_parts(hand.name):
        vs, fs = groups["palm" if link == hand.palm_link else "fingers"]
        fs.append(faces + sum(len(v) for v in vs))
        vs.append(transform_points(poses[link], vertices))
    return {
        key: (np.vstack(vs).astype(np.float32), np.vstack(fs).astype(np.uint32))
        for key, (vs, fs) in groups.items()
        if vs
    }


def hand_skeleton(hand: Hand, joints: Sequence[float]) -> np.ndarray:
    """A stick figure of the hand at ``joints``: (N, 2, 3) line segments in the palm frame (metres).

    The wrist axis (from the palm face back to the end of the palm, along -approach), a segment
    from each link's parent frame to its own, and from each fingertip link to the centre of its
    far end.
    """
    poses = hand.link_poses(joints)

    def visual_points(link: str) -> np.ndarray:
        pts = [transform_points(poses[link], v) for part, v, _ in _visual_parts(hand.name) if part == link]
        return np.vstack(pts) if pts else poses[link][None, :3, 3]

    palm = visual_points(hand.palm_link)
    approach = np.asarray(hand.approach, float)
    segments = [(np.zeros(3), approach * float(np.min(palm @ approach)))]
    parents = {j.child: j.parent for j in hand.model.joints}
    for link, parent in parents.items():
        origin = poses[link][:3, 3]
        segments.append((poses[parent][:3, 3], origin))
        if link not in parents.values():  # a fingertip link: on to the middle of its far end
            pts = visual_points(link)
            d = np.linalg.norm(pts - origin, axis=1)
            segments.append((origin, pts[d >= 0.9 * d.max()].mean(axis=0)))
    return np.asarray(segments, dtype=np.float64)


@dataclass(eq=False)
class _HandNodes:
    """One drawn hand: its palm frame, the frame holding its link meshes (``solid``), its stick
    figure (planned grasps only), which grasp (index in its segment's list) it shows, and whether
    as planned or as executed on the true object."""

    frame: viser.SceneNodeHandle
    solid: viser.SceneNodeHandle
    skeleton: viser.SceneNodeHandle | None
    index: int
    executed: bool
    pick_points: np.ndarray  # (N, 3) world metres along the stick figure, for click picking


class GraspDrawing:
    """The drawn hands of every segment, their styles and picking them with a click ray.

    Drawing runs in the grasp job's thread while GUI callbacks restyle and pick: one lock guards
    the nodes.
    """

    def __init__(self, audience: Audience) -> None:
        self.audience = audience
        self.lock = threading.RLock()
        self._roots: dict[int, viser.SceneNodeHandle] = {}
        self._hands: dict[tuple[int, str], _HandNodes] = {}  # (segment, node key "g<k>" | "exec_g<k>")

    def remove_segment(self, sid: int) -> None:
        """Remove segment ``sid``'s hands (and true object)."""
        with self.lock:
            root = self._roots.pop(sid, None)
            if root is not None:
                root.remove()  # removes every descendant too
            for key in [k for k in self._hands if k[0] == sid]:
                del self._hands[key]

    def clear(self) -> None:
        """Remove every segment's nodes."""
        with self.lock:
            for sid in list(self._roots):
                self.remove_segment(sid)

    def draw_segment(self, s: SegmentGrasps) -> None:
        """(Re)draw a segment's planned hands, and its executions if any."""
        sid = s.segment_id
        with self.lock:
            self.remove_segment(sid)
            self._roots[sid] = self.audience.scene.add_frame(f"/grasps/seg_{sid}", show_axes=False)
            hand = get_hand(s.hand)
            for k, (g, color) in enumerate(zip(s.grasps, epsilon_colors([g.epsilon for g in s.grasps]))):
                self._draw_hand(sid, k, False, hand, g.T_world_palm, g.joints, color, None)
            self.draw_executions(s)

    def draw_executions(self, s: SegmentGrasps, indices: Sequence[int] | None = None) -> None:
        """The true object and the executed hands ``indices`` (None: all executed) of segment ``s``."""
        sid = s.segment_id
        if s.truth_world is None:
            return
        with self.lock:
            self.audience.scene.add_mesh_simple(
                f"/grasps/seg_{sid}/truth",
                np.asarray(s.truth_world.vertices, np.float32),
                np.asarray(s.truth_world.faces, np.uint32),
                color=TRUTH_COLOR,
                opacity=TRUTH_OPACITY,
                cast_shadow=False,
                receive_shadow=False,
            )
            hand = get_hand(s.hand)
            for k in range(len(s.executions)) if indices is None else indices:
                e = s.executions[k]
                if e is not None:
                    self._draw_hand(sid, k, True, hand, e.T_world_palm, e.joints, EXECUTED_COLOR, EXECUTED_OPACITY)

    def _draw_hand(
        self,
        sid: int,
        k: int,
        executed: bool,
        hand: Hand,
        T_world_palm: np.ndarray,
        joints: dict[str, float],
        color: tuple[int, int, int],
        opacity: float | None,
    ) -> None:
        """Grasp ``k``'s hand at ``T_world_palm`` (world) with ``joints`` (replacing an earlier drawing
        of it): a palm frame, under it the ``hand/palm`` and ``hand/fingers`` meshes in the palm
        frame and, for a planned grasp, the ``skeleton`` stick figure; both in ``color``."""
        key = f"exec_g{k}" if executed else f"g{k}"
        old = self._hands.pop((sid, key), None)
        if old is not None:
            old.frame.remove()
        name = f"/grasps/seg_{sid}/{key}"
        scene = self.audience.scene
        frame = scene.add_frame(
            name,
            show_axes=False,
            position=T_world_palm[:3, 3],
            wxyz=viser.transforms.SO3.from_matrix(T_world_palm[:3, :3]).wxyz,
        )
        solid = scene.add_frame(f"{name}/hand", show_axes=False)
        q = [joints[n] for n in hand.joint_names]
        for part, (vertices, faces) in hand_solids(hand, q).items():
            scene.add_mesh_simple(
                f"{name}/hand/{part}",
                vertices,
                faces,
                color=shade(np.asarray(color), PALM_SHADE) if part == "palm" else color,
                opacity=opacity,
                cast_shadow=False,
                receive_shadow=False,
            )
        sticks = hand_skeleton(hand, q)
        skeleton = (
            None
            if executed
            else scene.add_line_segments(
                f"{name}/skeleton", sticks.astype(np.float32), color, thickness=SKELETON_THICKNESS
            )
        )
        pick_points = transform_points(T_world_palm, sample_segments(sticks, PICK_SPACING))
        self._hands[(sid, key)] = _HandNodes(frame, solid, skeleton, k, executed, pick_points)

    def restyle(self, current: int | None, selected: int | None, show_all: bool) -> None:
        """Grasp ``selected`` of segment ``current`` as a solid hand; the others as stick figures
        (``show_all``) or hidden; an execution only with its grasp selected, and then the planned
        hand as a stick figure so that it does not hide the executed one (which is often where
        the planned one was)."""
        with self.lock:
            for (sid, _key), nodes in self._hands.items():
                chosen = sid == current and nodes.index == selected
                nodes.frame.visible = chosen or (show_all and not nodes.executed)
                solid = chosen and (nodes.executed or (sid, f"exec_g{nodes.index}") not in self._hands)
                nodes.solid.visible = solid
                if nodes.skeleton is not None:
                    nodes.skeleton.visible = not solid

    def pick(self, current: int | None, ray_origin: np.ndarray, ray_direction: np.ndarray) -> tuple[int | None, float]:
        """``(index, t)`` of segment ``current``'s grasp whose visible planned hand a world-frame
        click ray hits first, ``t`` metres along the ray; ``(None, inf)`` when it misses them all."""
        with self.lock:
            shown = {
                nodes.index: nodes.pick_points
                for (sid, _key), nodes in self._hands.items()
                if sid == current and not nodes.executed and nodes.frame.visible
            }
        return first_hit(ray_origin, ray_direction, shown, PICK_TOLERANCE)
