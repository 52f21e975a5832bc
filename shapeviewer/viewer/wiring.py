"""The Pipeline tab's controls wired to the session: which method each button, dropdown and
checkbox calls. Kept apart from :mod:`.session` so the session reads as its jobs, this as its
layout's events."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import viser

from .jobs import send_download

if TYPE_CHECKING:
    from .session import Session


def wire_callbacks(app: Session) -> None:
    """Connect every control of ``app.panel`` and the scene's clicks to the session ``app``'s methods."""
    p = app.panel

    @app.audience.scene.on_click()
    def _(event: viser.SceneClickEvent) -> None:
        if app.drawing.visible:  # the dataset is on screen: its clicks are not picks
            app.click(np.asarray(event.ray_origin), np.asarray(event.ray_direction), event.client)

    # First, so that a segment's grasps are listed before completing it starts.
    p.segment.on_update(lambda _event: app.grasps.follow_segment(app.segment_options.get(p.segment.value)))

    @p.segment.on_update
    def _(event: viser.GuiEvent) -> None:
        sid = app.segment_options.get(p.segment.value)
        if event.client is None or sid == app.selected:
            return  # set by the app itself, or no change
        if sid is None:
            app.selected = None
        else:
            app.complete(sid, event.client)

    @p.complete.on_click
    def _(event: viser.GuiEvent) -> None:
        if app.selected is None:
            app.notify(event.client, "No segment selected", "Click a segment or pick one above.", "yellow")
        else:
            app.complete(app.selected, event.client)

    @p.complete_all.on_click
    def _(event: viser.GuiEvent) -> None:
        app.complete_all(event.client)

    for button, kind in ((p.detailed, "detailed"), (p.partial, "partial"), (p.mirror, "mirror"), (p.hull, "hull")):

        def compute(event: viser.GuiEvent, kind: str = kind) -> None:
            app.compute_mesh(kind, None, event.client)

        button.on_click(compute)

    @p.new_scene.on_click
    def _(event: viser.GuiEvent) -> None:
        app.load_default(int(p.seed.value), event.client)

    @p.upload.on_upload
    def _(event: viser.GuiEvent) -> None:
        file = p.upload.value
        app.load_upload(file.name, file.content, event.client)

    if p.load_cloud is not None and p.cloud_path is not None:
        cloud_path = p.cloud_path

        @p.load_cloud.on_click
        def _(event: viser.GuiEvent) -> None:
            app.load_data_file(cloud_path.value, event.client)

    for key, box in p.layers.items():

        def toggle(_event: viser.GuiEvent, key: str = key, box: viser.GuiCheckboxHandle = box) -> None:
            app.drawing.set_layer(key, box.value)

        box.on_update(toggle)

    @p.layers["confidence"].on_update
    def _(_event: viser.GuiEvent) -> None:
        if p.layers["confidence"].value:
            # Every completion's layer; the selected segment's figures last, so the panel shows them.
            done = sorted(app.completions.values(), key=lambda c: c.segment_id == app.selected)
            for c in done:
                app.show_confidence(c)

    @p.sample.on_update
    def _(event: viser.GuiEvent) -> None:
        if event.client is not None:  # moved by the user, not reset by the app
            app.show_sample(int(p.sample.value), event.client)

    @p.cloud_colors.on_update
    def _(_event: viser.GuiEvent) -> None:
        if app.scene is not None:
            app.drawing.draw_cloud(app.scene, p.cloud_colors.value == "capture")

    @p.shade_output.on_update
    @p.layers["cnn_output"].on_update
    def _(_event: viser.GuiEvent) -> None:
        # The CNN output is drawn only while its layer is shown (see PipelineDrawing.draw_completion).
        if app.scene is not None and p.layers["cnn_output"].value:
            for c in list(app.completions.values()):
                app.drawing.draw_output(app.scene, c, p.shade_output.value)

    for button, kind in ((p.export_points, "points"), (p.export_grids, "grids"), (p.export_mesh, "mesh")):

        def export(event: viser.GuiEvent, kind: str = kind) -> None:
            send_download(
                event.client,
                lambda: app.export_bytes(
                    kind, None, p.mesh_format.value, p.export_frame.value, p.export_mesh_kind.value
                ),
                app.notify,
            )

        button.on_click(export)
