"""The Dataset tab's 3D scene: one view's items, labels, sensor and best grasps under :data:`ROOT`,
and the browser cameras while the dataset is on screen.

Positions are display-frame metres (see :mod:`.layout`); the store's meshes and points are in
their view's camera frame and are mapped with ``ViewLayout.T_display_cam``.

viser's 3D scene is shared by the tabs (and the browser does not report tab changes), so
everything is drawn under its own root frame, visible only while the dataset is shown.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh
import viser

from ...evaluation.results import ResultsStore, read_mesh, read_points
from ...evaluation.summaries import GraspSummary, ViewInfo
from ...perception.camera import Intrinsics, transform_points
from ..audience import Audience
from .layout import DEFAULT_ASPECT, ViewLayout
from .summary import COLORS

log = logging.getLogger(__name__)

ROOT = "/dataset"
# Display budget: meshes with more triangles are decimated for display (exports use the files).
DISPLAY_MAX_FACES = 20_000
DISPLAY_CACHE = 96  # display meshes kept in memory (about 16 views; a few hundred kB each)
POINT_SIZE = 0.003  # metres; viser draws points about twice this wide
PLANNED_HAND = ((70, 140, 255), 0.3)  # colour, opacity: the completion stays visible through the hand
EXECUTED_HAND = ((250, 90, 60), 0.5)
# A hand to draw: node name, display-frame vertices (float32, metres), faces, colour, opacity.
HandMesh = tuple[str, np.ndarray, np.ndarray, tuple[int, int, int], float]
# A hand of a column before the layout: its column (method), then as HandMesh with the vertices
# in the view's camera frame (float64, metres).
ColumnHand = tuple[str, str, np.ndarray, np.ndarray, tuple[int, int, int], float]


def points_colors(depth: np.ndarray) -> np.ndarray:
    """uint8 RGB (N, 3) of the partial view's colour, light for points near the sensor, dark for far ones."""
    d = np.asarray(depth, dtype=np.float64)
    lo, hi = np.percentile(d, [2, 98]) if len(d) else (0.0, 1.0)
    x = np.clip((d - lo) / max(hi - lo, 1e-6), 0.0, 1.0)[:, None]
    near, far = np.array([120, 185, 255]), np.array([20, 60, 150])
    return (near + (far - near) * x).astype(np.uint8)


def decimate(mesh: trimesh.Trimesh, max_faces: int = DISPLAY_MAX_FACES) -> trimesh.Trimesh:
    """``mesh`` with at most ``max_faces`` triangles (quadric decimation, open3d), for display only."""
    if len(mesh.faces) <= max_faces:
        return mesh
    import open3d as o3d

    m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.asarray(mesh.vertices, np.float64)),
        o3d.utility.Vector3iVector(np.asarray(mesh.faces, np.int32)),
    )
    m = m.simplify_quadric_decimation(target_number_of_triangles=int(max_faces))
    return trimesh.Trimesh(np.asarray(m.vertices), np.asarray(m.triangles), process=False)


class DisplayMeshes:
    """Display copies of a store's files, the most recently used kept in memory.

    Stepping back and forth between views reads and decimates each file once; the key includes
    the modification time, so a file that a running evaluation rewrites is read again.
    """

    def __init__(self, size: int = DISPLAY_CACHE) -> None:
        self.size = size
        self._cache: OrderedDict[tuple[str, int], tuple[np.ndarray, np.ndarray | None]] = OrderedDict()

    def get(self, path: Path, points: bool) -> tuple[np.ndarray, np.ndarray | None]:
        """``(vertices, faces)`` of a mesh file (camera frame, decimated for display), or
        ``(points, None)`` of a points file; float32 metres, int32 faces."""
        key = (str(path), path.stat().st_mtime_ns)
        hit = self._cache.get(key)
        if hit is not None:
            self._cache.move_to_end(key)
            return hit
        value: tuple[np.ndarray, np.ndarray | None]
        if points:
            value = (read_points(path).astype(np.float32), None)
        else:
            m = decimate(read_mesh(path))
            value = (np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.int32))
        self._cache[key] = value
        while len(self._cache) > self.size:
            self._cache.popitem(last=False)
        return value


def best_grasp_hands(
    store: ResultsStore, info: ViewInfo, grasps: list[GraspSummary], kinds: tuple[str, ...]
) -> list[ColumnHand]:
    """The hands of each completion's best planned grasp (blue) and of its execution on the true
    object (red), for the columns ``kinds``, in the view's camera frame (the layout makes room
    for them, :func:`place_hands` puts them in their columns). A grasp file that cannot be read
    is skipped with a warning: the labels still show its summary."""
    from ...grasp.hands import get_hand, hand_mesh

    hands = []
    for g in grasps:
        if not g.file or g.method not in kinds:
            continue
        try:
            gs = store.grasp_set(info.object, info.view, g.method, g.hand)
        except Exception as e:  # an unreadable grasp file: the labels still show the summary
            log.warning("grasps of %s view %d %s: %s", info.object, info.view, g.method, e)
            continue
        if gs is None:
            continue
        # The completion's own grasps: not those a wider search planned on the grasp envelope.
        first = int(gs.meta.get("wider", {}).get("first", len(gs.grasps)))
        if not first:
            continue
        # Grasp files are in a "world" frame; the evaluation records its camera pose there.
        T_world_cam = np.asarray(gs.meta.get("T_world_cam", np.eye(4)), dtype=np.float64)
        T_cam_world = np.linalg.inv(T_world_cam)
        best = max(range(first), key=lambda i: gs.grasps[i].epsilon)
        hand = get_hand(gs.grasps[best].hand)
        states = [("planned", gs.grasps[best], PLANNED_HAND)]
        if gs.executions[best] is not None:
            states.append(("executed", gs.executions[best], EXECUTED_HAND))
        for tag, state, (color, opacity) in states:
            mesh = hand_mesh(hand, [state.joints[n] for n in hand.joint_names])
            T = T_cam_world @ np.asarray(state.T_world_palm)
            hands.append(
                (
                    g.method,
                    f"{ROOT}/grasp_{g.method}_{tag}",
                    transform_points(T, mesh.vertices),
                    np.asarray(mesh.faces, np.int32),
                    color,
                    opacity,
                )
            )
    return hands


def place_hands(hands: list[ColumnHand], layout: ViewLayout) -> list[HandMesh]:
    """:func:`best_grasp_hands` moved into their columns (display frame)."""
    return [
        (name, transform_points(layout.T_display_cam[kind], verts).astype(np.float32), faces, color, opacity)
        for kind, name, verts, faces, color, opacity in hands
    ]


def hand_extents(hands: list[ColumnHand]) -> dict[str, np.ndarray]:
    """Column -> the camera-frame vertices of its hands (for :func:`~.layout.layout_view`)."""
    out: dict[str, list[np.ndarray]] = {}
    for kind, _name, verts, *_ in hands:
        out.setdefault(kind, []).append(verts)
    return {kind: np.concatenate(v) for kind, v in out.items()}


class DatasetScene:
    """The dataset's scene nodes under :data:`ROOT`, and the browser cameras it moves."""

    def __init__(self, audience: Audience) -> None:
        self.audience = audience
        self.root: viser.FrameHandle | None = None  # there while the dataset is on screen
        self.nodes: list[str] = []  # names of the drawn view's nodes
        self._saved_cameras: dict[int, tuple] = {}  # client id -> (fov, up, position, look_at) to restore

    def draw(
        self,
        layout: ViewLayout,
        kinds: tuple[str, ...],
        items: dict[str, tuple[np.ndarray, np.ndarray | None]],
        labels: dict[str, str],
        hands: list[HandMesh],
    ) -> None:
        """Replace the drawn view: a floor, each of ``kinds`` in its column (``items``: camera-frame
        ``(vertices, faces)``, faces None for points) under its label, the sensor, and ``hands``."""
        self.clear()
        scene = self.audience.scene
        self._add(
            scene.add_grid,
            f"{ROOT}/floor",
            width=layout.spacing * (len(kinds) + 0.4),
            height=layout.spacing * 1.6,
            plane="xy",
            cell_size=0.05,
            section_size=layout.spacing,
            plane_color=(236, 232, 224),
            plane_opacity=0.5,
            shadow_opacity=0.0,
            cell_color=(215, 210, 200),
            section_color=(190, 185, 175),
        )
        for kind in kinds:
            if kind in items:
                verts, faces = items[kind]
                pts = transform_points(layout.T_display_cam[kind], verts).astype(np.float32)
                if faces is None:
                    # Shaded by depth from the sensor (near light, far dark): a flat colour hides the shell's shape.
                    self._add(
                        scene.add_point_cloud,
                        f"{ROOT}/{kind}",
                        pts,
                        points_colors(verts[:, 2]),
                        point_size=POINT_SIZE,
                        precision="float32",
                        point_shading="flat",
                    )
                else:
                    self._add(
                        scene.add_mesh_simple,
                        f"{ROOT}/{kind}",
                        pts,
                        faces,
                        color=COLORS[kind],
                        cast_shadow=False,
                        receive_shadow=False,
                        flat_shading=False,
                    )
            self._add(
                scene.add_label,
                f"{ROOT}/label_{kind}",
                labels[kind],
                position=layout.columns[kind] + [0.0, 0.0, layout.top + 0.12 * layout.spacing],
                anchor="bottom-center",
                font_screen_scale=0.8,
            )
        if "points" in items:
            kinect = Intrinsics.kinect()  # the evaluation renders its views with the Kinect's intrinsics
            self._add(
                scene.add_camera_frustum,
                f"{ROOT}/sensor",
                fov=kinect.vertical_fov,
                aspect=kinect.aspect,
                scale=0.12 * layout.spacing,
                thickness=0.004 * layout.spacing,
                color=(60, 60, 60),
                wxyz=viser.transforms.SO3.from_matrix(layout.sensor_rotation).wxyz,
                position=layout.sensor_position,
            )
        for name, vertices, faces, color, opacity in hands:
            self._add(
                scene.add_mesh_simple,
                name,
                vertices,
                faces,
                color=color,
                opacity=opacity,
                cast_shadow=False,
                receive_shadow=False,
            )

    def show_root(self) -> None:
        """Put the (empty) dataset root in the scene, if it is not there.

        The root is added and removed, never hidden: viser 1.1's browser leaves labels under a
        frame that was hidden (or just shown) undrawn until the camera moves."""
        if self.root is None:
            self.root = self.audience.scene.add_frame(ROOT, show_axes=False)

    def remove_root(self) -> None:
        """Take the dataset root and the drawn view off the scene."""
        if self.root is not None:
            self.root.remove()  # removes every node under it too
            self.root = None
        self.nodes = []

    def _add(self, make: Callable[..., viser.SceneNodeHandle], name: str, *args, **kwargs) -> None:
        make(name, *args, **kwargs)
        self.nodes.append(name)

    def clear(self) -> None:
        """Remove the drawn view's nodes."""
        for name in self.nodes:
            h = self.audience.scene.get_handle_by_name(name)
            if h is not None:
                h.remove()
        self.nodes = []

    def handles(self) -> dict[str, viser.SceneNodeHandle]:
        """The drawn view's nodes now in the session's scene, by name."""
        found = {name: self.audience.scene.get_handle_by_name(name) for name in self.nodes}
        return {name: h for name, h in found.items() if h is not None}

    def aspect(self, client: viser.ClientHandle | None) -> float:
        """Canvas width / height of ``client`` (default: the first that reported its camera)."""
        for c in [client] if client is not None else list(self.audience.get_clients().values()):
            try:
                return float(c.camera.aspect)
            except (AssertionError, AttributeError):  # no camera reported yet
                continue
        return DEFAULT_ASPECT

    def aim_cameras(self, layout: ViewLayout, fov: float) -> None:
        """Point every browser camera at ``layout``'s row (``fov``: vertical, radians), remembering
        how each was set the first time so that :meth:`restore_cameras` can put it back."""
        for c in self.audience.get_clients().values():
            try:
                with c.atomic():
                    if c.client_id not in self._saved_cameras:
                        cam = c.camera
                        self._saved_cameras[c.client_id] = (
                            cam.fov,
                            tuple(cam.up_direction),
                            tuple(cam.position),
                            tuple(cam.look_at),
                        )
                    c.camera.fov = fov
                    c.camera.up_direction = (0.0, 0.0, 1.0)
                    c.camera.position = layout.camera_position
                    c.camera.look_at = layout.look_at
            except AssertionError:  # the client has not reported its camera yet
                pass

    def restore_cameras(self) -> None:
        """Put every browser camera back as it was before :meth:`aim_cameras`."""
        for c in self.audience.get_clients().values():
            saved = self._saved_cameras.pop(c.client_id, None)
            if saved is None:
                continue
            try:
                with c.atomic():
                    c.camera.fov, c.camera.up_direction, c.camera.position, c.camera.look_at = saved
            except AssertionError:  # camera not reported yet
                pass
