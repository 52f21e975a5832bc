"""The Pipeline tab's scene nodes: every stage of the pipeline drawn in the WORLD frame (metres, z up).

Every stage is a layer, a frame ``/<layer key>`` (see :data:`panel.LAYERS`) whose children are
that stage's nodes, e.g. ``/segments/seg_3``, ``/cnn_input/seg_3``, ``/fast_mesh/seg_3``; the
layer checkbox toggles the frame's visibility. ``/sensor`` is the camera frustum and ``/table``
the table-plane hint. Pipeline results come in the camera optical frame and are mapped with the
scene's ``T_world_cam`` before they are sent.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np
import trimesh
import viser

from ..completion.pipeline import Completion
from ..perception.camera import Intrinsics, transform_points
from .audience import Audience
from .panel import LAYERS, MESH_KINDS
from .state import LoadedScene
from .visuals import default_view, depth_colors, probability_colors, shade, spread_colors, surface_voxels, voxel_cubes

CLOUD_POINT_SIZE = 0.0015  # metres; viser draws points about twice this wide
SEGMENT_POINT_SIZE = 0.002  # a little larger, so segment colours win over the cloud at the same spots
INPUT_VOXEL_FILL = 0.5  # cube edge / voxel edge: small cubes let the fast mesh show between them
OUTPUT_VOXEL_FILL = 0.95
# Fixed colours for the baselines, so that they never pass for one of our own (segment-coloured) meshes.
PARTIAL_COLOR = (160, 160, 160)
MIRROR_COLOR = (110, 150, 215)
HULL_COLOR = (150, 120, 190)
SAMPLE_COLOR = (120, 60, 160)  # the Confidence layer's purple: a sample is a guess
ENVELOPE_OPACITY = 0.35
# Points sent to a browser per scene (the cloud and the segments; picking and the pipeline use all
# of them): a browser draws 300k points smoothly, millions not at all. The segments get up to
# MAX_SEGMENT_POINTS of the budget, the cloud the rest.
MAX_SENT_POINTS = 300_000
MAX_SEGMENT_POINTS = 100_000


class PipelineDrawing:
    """Adds, replaces and removes the pipeline's scene nodes (remembered so a new scene can clear them).

    Args:
        audience: the browser tab (or every browser) to draw for.
        max_cloud_points: draw at most this many points of the Cloud layer (None = what is left of
            :data:`MAX_SENT_POINTS` after the segments).
    """

    def __init__(self, audience: Audience, max_cloud_points: int | None = None) -> None:
        self.audience = audience
        self.max_cloud_points = max_cloud_points
        self.nodes: dict[str, viser.SceneNodeHandle] = {}
        self.layer_roots = {
            layer.key: audience.scene.add_frame(f"/{layer.key}", show_axes=False, visible=layer.visible)
            for layer in LAYERS
        }
        self.visible = True  # False while the Dataset tab shows its scene

    # ------------------------------------------------------------------------------------------
    # Visibility

    def set_visible(self, visible: bool, checked: Mapping[str, bool]) -> None:
        """Show or hide every pipeline node; a shown layer follows its checkbox (``checked``: key -> value)."""
        self.visible = visible
        for key, root in self.layer_roots.items():
            root.visible = visible and checked[key]
        for name in ("/sensor", "/table"):
            if name in self.nodes:
                self.nodes[name].visible = visible

    def set_layer(self, key: str, checked: bool) -> None:
        """A layer checkbox changed: the layer shows when it is checked and the pipeline is shown."""
        self.layer_roots[key].visible = checked and self.visible

    # ------------------------------------------------------------------------------------------
    # Nodes

    def add(self, name: str, make: Callable[..., viser.SceneNodeHandle], *args, **kwargs) -> None:
        """Add (or replace) scene node ``name`` with ``make(name, *args, **kwargs)``."""
        self.nodes[name] = make(name, *args, **kwargs)

    def remove(self, name: str) -> None:
        handle = self.nodes.pop(name, None)
        if handle is not None:
            handle.remove()

    def clear(self) -> None:
        """Remove every node of the scene (the layer frames stay)."""
        for name in list(self.nodes):
            self.remove(name)

    def sent_points(self) -> int:
        """How many cloud and segment points the browsers were sent."""
        total = 0
        for name, h in self.nodes.items():
            if name == "/cloud/points" or name.startswith("/segments/seg_"):
                assert isinstance(h, viser.PointCloudHandle)  # added by draw_cloud / draw_segments
                total += len(h.points)
        return total

    # ------------------------------------------------------------------------------------------
    # A scene

    def show_scene(self, scene: LoadedScene, capture_colors: bool) -> None:
        """Replace every node with ``scene``'s cloud, segments, sensor and table, and aim the cameras at it."""
        self.clear()
        self.draw_cloud(scene, capture_colors)
        self.draw_segments(scene)
        self.draw_sensor_and_table(scene)
        self.set_default_view(scene)

    def draw_cloud(self, scene: LoadedScene, capture_colors: bool) -> None:
        """The Cloud layer: the capture's colours (``capture_colors`` and it has them) or depth colours."""
        capture, T = scene.capture, scene.T_world_cam
        valid = capture.valid_mask()
        pts_cam = capture.flat_points()[valid]
        flat_colors = capture.flat_colors() if capture_colors else None  # None when the capture has none
        if flat_colors is not None:
            colors = flat_colors[valid]
        else:
            colors = depth_colors(pts_cam[:, 2])
        budget = MAX_SENT_POINTS - sum(len(p) for p in scene.display_points(MAX_SEGMENT_POINTS).values())
        if self.max_cloud_points is not None:
            budget = min(budget, self.max_cloud_points)
        if len(pts_cam) > budget:
            keep = np.random.default_rng(0).choice(len(pts_cam), budget, replace=False)
            pts_cam, colors = pts_cam[keep], colors[keep]
        self.add(
            "/cloud/points",
            self.audience.scene.add_point_cloud,
            transform_points(T, pts_cam),
            colors,
            point_size=CLOUD_POINT_SIZE,
            precision="float32",
            point_shading="flat",
        )

    def draw_segments(self, scene: LoadedScene) -> None:
        shown = scene.display_points(MAX_SEGMENT_POINTS)
        for sid, seg in scene.segments.items():
            pts = shown[sid]
            if len(pts) == 0:
                continue
            self.add(
                f"/segments/seg_{sid}",
                self.audience.scene.add_point_cloud,
                pts,
                tuple(int(v) for v in seg.color),
                point_size=SEGMENT_POINT_SIZE,
                precision="float32",
            )
            top = pts[np.argmax(pts[:, 2])]
            self.add(
                f"/segments/label_{sid}",
                self.audience.scene.add_label,
                str(sid),
                position=top + np.array([0.0, 0.0, 0.03]),
                anchor="bottom-center",
                font_screen_scale=0.9,
            )

    def draw_sensor_and_table(self, scene: LoadedScene) -> None:
        T = scene.T_world_cam
        intr = scene.capture.intrinsics or Intrinsics.kinect()
        wxyz = viser.transforms.SO3.from_matrix(T[:3, :3]).wxyz
        self.add(
            "/sensor",
            self.audience.scene.add_camera_frustum,
            fov=intr.vertical_fov,
            aspect=intr.aspect,
            scale=0.08,
            thickness=0.003,
            color=(60, 60, 60),
            wxyz=wxyz,
            position=T[:3, 3],
        )
        focus, _ = scene.focus()
        # The table (or floor) is the plane z = 0 of the world frame.
        self.add(
            "/table",
            self.audience.scene.add_grid,
            width=1.5,
            height=1.5,
            plane="xy",
            cell_size=0.1,
            section_size=0.5,
            position=(focus[0], focus[1], 0.0),
            plane_color=(235, 230, 220),
            plane_opacity=0.35,
            shadow_opacity=0.0,
        )

    def set_default_view(self, scene: LoadedScene) -> None:
        """Point the browsers' cameras at the scene's objects from the sensor's side."""
        focus, extent = scene.focus()
        position, look_at = default_view(scene.T_world_cam, focus, max(extent, 0.3))
        self.audience.point_cameras(position, look_at)

    # ------------------------------------------------------------------------------------------
    # A completion

    def draw_completion(self, scene: LoadedScene, c: Completion, shade_output: bool, show_output: bool) -> None:
        """Draw one completion's CNN input, meshes and (``show_output``: its layer is on) CNN
        output in the world frame.

        A new completion has no detailed or baseline mesh yet, so this also removes those of an
        earlier completion of the same segment. The CNN output's cubes are a sixth of what a click
        sends and their layer starts hidden, so they are drawn only once it is shown.
        """
        sid = c.segment_id
        color = np.asarray(scene.segments[sid].color)
        # The fast mesh goes first: it is what the user waits for (and what the benchmark times).
        self.draw_mesh(scene, "fast", sid, c.fast_mesh)
        for kind in MESH_KINDS:
            if kind != "fast":  # made on request: an earlier completion's
                self.draw_mesh(scene, kind, sid, None)
        self.draw_voxels(
            scene, f"/cnn_input/seg_{sid}", surface_voxels(c.grid_in), c, INPUT_VOXEL_FILL, shade(color, 0.55)
        )
        if show_output:
            self.draw_output(scene, c, shade_output)
        else:
            self.remove(f"/cnn_output/seg_{sid}")  # an earlier completion's: drawn again when shown

    def draw_mesh(self, scene: LoadedScene, kind: str, sid: int, mesh: trimesh.Trimesh | None) -> None:
        """Draw (or, when None, remove) segment ``sid``'s camera-frame mesh ``kind`` in the world frame."""
        name = f"/{kind}_mesh/seg_{sid}"
        if mesh is None:
            self.remove(name)
            return
        color = np.asarray(scene.segments[sid].color)
        colors = {
            "fast": shade(color, 1.35),
            "detailed": shade(color, 0.7),
            "envelope": SAMPLE_COLOR,
            "partial": PARTIAL_COLOR,
            "mirror": MIRROR_COLOR,
            "hull": HULL_COLOR,
        }
        self.add(
            name,
            self.audience.scene.add_mesh_simple,
            transform_points(scene.T_world_cam, mesh.vertices),
            np.asarray(mesh.faces),
            color=colors[kind],
            # The envelope wraps the completion: see-through, so the completion shows inside it.
            opacity=ENVELOPE_OPACITY if kind == "envelope" else None,
            cast_shadow=False,
            receive_shadow=False,
        )

    def draw_output(self, scene: LoadedScene, c: Completion, shade_output: bool) -> None:
        """The CNN output's surface voxels, shaded by probability (``shade_output``) or in the segment's colour."""
        idx = surface_voxels(c.grid_out)
        colors: np.ndarray | tuple[int, int, int]
        if shade_output:
            colors = probability_colors(c.probabilities[tuple(idx.T)], c.grid_level)
        else:
            colors = shade(np.asarray(scene.segments[c.segment_id].color), 1.5)
        self.draw_voxels(scene, f"/cnn_output/seg_{c.segment_id}", idx, c, OUTPUT_VOXEL_FILL, colors)

    def draw_confidence(self, scene: LoadedScene, c: Completion, spread: np.ndarray) -> None:
        """The surface voxels of the completed solid coloured by ``spread`` (per voxel of the grid,
        how much sample completions disagree: :func:`~shapeviewer.completion.model.sample_spread`)."""
        idx = surface_voxels(c.solid)
        self.draw_voxels(
            scene, f"/confidence/seg_{c.segment_id}", idx, c, OUTPUT_VOXEL_FILL, spread_colors(spread[tuple(idx.T)])
        )

    def draw_sample(self, scene: LoadedScene, sid: int, mesh: trimesh.Trimesh | None) -> None:
        """One sample completion's camera-frame fast mesh of segment ``sid`` in the Confidence
        layer, translucent over the completion (None: remove it)."""
        name = f"/confidence/sample_seg_{sid}"
        if mesh is None:
            self.remove(name)
            return
        self.add(
            name,
            self.audience.scene.add_mesh_simple,
            transform_points(scene.T_world_cam, mesh.vertices),
            np.asarray(mesh.faces),
            color=SAMPLE_COLOR,
            opacity=0.75,
            cast_shadow=False,
            receive_shadow=False,
        )

    def draw_voxels(
        self,
        scene: LoadedScene,
        name: str,
        indices: np.ndarray,
        c: Completion,
        fill: float,
        colors: np.ndarray | tuple[int, int, int],
    ) -> None:
        """Cubes (``fill`` of a voxel's edge) at voxels ``indices`` of ``c``'s grid; removed when there are none."""
        if len(indices) == 0:
            self.remove(name)
            return
        cubes = voxel_cubes(indices, c.frame, scene.T_world_cam, fill)
        identity = np.broadcast_to(np.array([1.0, 0.0, 0.0, 0.0], np.float32), (len(indices), 4))
        self.add(
            name,
            self.audience.scene.add_batched_meshes_simple,
            cubes.vertices,
            cubes.faces,
            batched_wxyzs=identity,
            batched_positions=cubes.positions,
            batched_colors=colors,
            lod="off",
            flat_shading=True,
            cast_shadow=False,
            receive_shadow=False,
        )
