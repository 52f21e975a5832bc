"""The viewer's control panel: GUI handles only, no behaviour (the app wires the callbacks).

Also the text the panel shows (markdown for the source, the model, the stage timings and a
completion's confidence), built from plain values so that it can be tested without a server.
"""

from __future__ import annotations

from dataclasses import dataclass

import viser

from ..completion.cuboid import Cuboid
from ..completion.model import SYMMETRIES
from ..completion.pipeline import GUESS_SPREAD, Completion
from ..completion.revolve import RevolutionAxis
from ..export import MESH_FORMATS
from .state import MESH_KINDS, MESH_TITLES

NO_SEGMENT = "(none)"
N_SAMPLES = len(SYMMETRIES)  # sample completions behind the Confidence layer and the Sample field
NO_DATA_FILE = "(no capture files)"
# The upload button's file filter (browsers match either the suffix or the MIME type).
UPLOAD_MIME_TYPES = ".pcd,.ply,.png,.npy"
MAX_UPLOAD_MB = 200
# Algorithm 1's steps, as keys of the ``timings`` dict that ``completion_detailed_mesh`` fills, with
# panel labels.
ALGORITHM_1_STEPS = (
    ("density", "density ratio"),
    ("upsample", "up-sample CNN output"),
    ("merge", "merge"),
    ("fill_gaps", "fill gaps"),
    ("smooth", "smooth"),
    ("marching_cubes", "marching cubes"),
)


@dataclass(frozen=True)
class Layer:
    """One stage of the pipeline drawn in the 3D view (its nodes live under ``/<key>``)."""

    key: str
    label: str
    visible: bool
    hint: str


LAYERS: tuple[Layer, ...] = (
    Layer("cloud", "Cloud", True, "The full captured point cloud (paper Fig. 5, step 1)."),
    Layer("segments", "Segments", True, "Object segments after table removal and Euclidean clustering (step 2)."),
    Layer("cnn_input", "CNN input", True, "Occupied voxels of the 40^3 input grid of each completed segment (step 3)."),
    Layer(
        "cnn_output",
        "CNN output",
        False,
        "Voxels the CNN marks occupied: its 40^3 grid of every voxel the surface passes through (step 4).",
    ),
    Layer(
        "confidence",
        "Confidence",
        False,
        "The completed voxels shaded by how much 8 sample completions disagree: pale = seen, dark purple = a guess.",
    ),
    Layer("fast_mesh", "Fast mesh", True, "Marching cubes of the CNN output, in metres (step 5a)."),
    Layer(
        "detailed_mesh",
        "Detailed mesh",
        False,
        "Algorithm 1: observed points merged with the CNN output, smoothed, meshed (step 5b).",
    ),
    Layer(
        "envelope_mesh",
        "Grasp envelope",
        False,
        "What the network thinks may be there (its 8 sample completions' mean above p = 0.3, wider than a "
        "completion where it hedges, as in a vessel). Plan grasps on it (Grasps > Plan on: envelope).",
    ),
    Layer("partial_mesh", "Partial baseline", False, "Baseline: marching cubes of the observed points alone."),
    Layer(
        "mirror_mesh",
        "Mirror baseline",
        False,
        "Baseline: the view mirrored about its best symmetry plane (Bohg et al. 2011).",
    ),
    Layer("hull_mesh", "Hull baseline", False, "Baseline: the convex hull of the observed points."),
    Layer("grasps", "Grasps", True, "Hands at the grasps planned on a segment's mesh, coloured by epsilon (step 6)."),
)


@dataclass
class Panel:
    """Handles of every control of the panel."""

    status: viser.GuiMarkdownHandle
    source: viser.GuiMarkdownHandle
    seed: viser.GuiNumberHandle
    new_scene: viser.GuiButtonHandle
    upload: viser.GuiUploadButtonHandle
    # Only with a data folder (``--data-dir``): its capture files, and the button that loads one.
    cloud_path: viser.GuiDropdownHandle | None
    load_cloud: viser.GuiButtonHandle | None
    model: viser.GuiMarkdownHandle
    model_folder: viser.GuiFolderHandle
    segment: viser.GuiDropdownHandle
    complete: viser.GuiButtonHandle
    complete_all: viser.GuiButtonHandle
    revolve: viser.GuiCheckboxHandle
    fit_boxes: viser.GuiCheckboxHandle
    detailed: viser.GuiButtonHandle
    partial: viser.GuiButtonHandle
    mirror: viser.GuiButtonHandle
    hull: viser.GuiButtonHandle
    timings: viser.GuiMarkdownHandle
    layers: dict[str, viser.GuiCheckboxHandle]
    cloud_colors: viser.GuiDropdownHandle
    shade_output: viser.GuiCheckboxHandle
    # A number field, not a slider: viser's client orbits the camera on arrow keys unless a text
    # field has the focus, and a slider's thumb is no text field (see build_panel).
    sample: viser.GuiNumberHandle
    export_frame: viser.GuiDropdownHandle
    mesh_format: viser.GuiDropdownHandle
    export_mesh_kind: viser.GuiDropdownHandle
    export_points: viser.GuiButtonHandle
    export_grids: viser.GuiButtonHandle
    export_mesh: viser.GuiButtonHandle

    @property
    def job_buttons(self) -> tuple[viser.GuiButtonHandle, ...]:
        """Buttons that start a job; disabled while one runs (double clicks would queue jobs)."""
        buttons = (
            self.new_scene,
            self.complete,
            self.complete_all,
            self.detailed,
            self.partial,
            self.mirror,
            self.hull,
        )
        return buttons if self.load_cloud is None else (*buttons, self.load_cloud)


def build_panel(gui: viser.GuiApi, seed: int, data_files: tuple[str, ...] | None = None) -> Panel:
    """Add the panel's controls to ``gui`` (all empty until a scene is loaded).

    ``data_files``: the capture files of the server's data folder (see :func:`data_file_options`) for
    the "Server file" dropdown; None (no data folder) leaves the dropdown and its button out.
    """
    gui.add_markdown("**Shape completion** — Varley et al., IROS 2017. Click a segment in the 3D view to complete it.")
    status = gui.add_markdown("_Loading the scene..._")
    with gui.add_folder("Source"):
        source = gui.add_markdown("")
    with gui.add_folder("Model") as model_folder:
        model = gui.add_markdown("")
    with gui.add_folder("Completion"):
        segment = gui.add_dropdown("Segment", (NO_SEGMENT,), hint="Pick a segment to complete (or click it in 3D)")
        complete = gui.add_button(
            "Complete segment",
            icon=viser.Icon.CUBE,
            hint="Fast-complete the selected segment anew (choosing a completed segment brings back what was "
            "made of it; this drops its detailed mesh and baselines)",
        )
        complete_all = gui.add_button(
            "Complete all", icon=viser.Icon.BOX_MULTIPLE, hint="Fast-complete every segment in one batched CNN pass"
        )
        revolve = gui.add_checkbox(
            "Revolve on table",
            False,
            hint="Revolve the network's answers about the table's normal where the segment looks like a surface "
            "of revolution (bowls, cups, cans): closes an upside-down bowl's far side, fattens cans and fruit",
        )
        fit_boxes = gui.add_checkbox(
            "Fit boxes on table",
            True,
            hint="Complete a segment whose points fill a rectangle on the table and lie on a box's faces as that "
            "box (the network's boxes are about 10 mm too large); untick for the network's own answer",
        )
        detailed = gui.add_button(
            "Detailed mesh",
            icon=viser.Icon.SPARKLES,
            hint="Algorithm 1's detailed mesh of the selected segment (a few seconds)",
        )
        with gui.add_folder("Baselines"):
            partial = gui.add_button(
                "Partial",
                icon=viser.Icon.CUBE_OFF,
                hint="Baseline: mesh of the selected segment's observed points alone",
            )
            mirror = gui.add_button(
                "Mirror",
                icon=viser.Icon.FLIP_VERTICAL,
                hint="Baseline: the selected segment completed by symmetry (needs a table)",
            )
            hull = gui.add_button(
                "Hull",
                icon=viser.Icon.POLYGON,
                hint="Baseline: the convex hull of the selected segment's observed points",
            )
        timings = gui.add_markdown("_No completion yet._")
    with gui.add_folder("Layers"):
        layers = {layer.key: gui.add_checkbox(layer.label, layer.visible, hint=layer.hint) for layer in LAYERS}
        cloud_colors = gui.add_dropdown(
            "Cloud colours", ("capture", "depth"), hint="Colour the cloud with the sensor's colours or by depth"
        )
        shade_output = gui.add_checkbox(
            "Shade by p",
            True,
            hint="Colour CNN output voxels by occupancy probability (yellow: barely in the grid, red: sure)",
        )
        # viser's client moves the camera on the arrow keys (and W/A/S/D/Q/E) wherever the focus is,
        # except in a text field (INPUT, TEXTAREA, SELECT): a slider's thumb would step the sample and
        # orbit the view at once, a number field's arrows step the sample alone.
        sample = gui.add_number(
            "Sample",
            0,
            min=0,
            max=N_SAMPLES,
            step=1,
            hint=f"Step through the CNN's {N_SAMPLES} sample completions of the selected segment with the arrows "
            "(0: none; 1: the view as seen, the others mirrored; the completion is their mean); "
            "where they differ, the network guesses",
        )
    with gui.add_folder("Load a scene"):
        seed_h = gui.add_number("Seed", seed, min=0, step=1, hint="Seed of the generated tabletop scene")
        new_scene = gui.add_button("New scene", icon=viser.Icon.DICE, hint="Generate the tabletop scene of this seed")
        upload = gui.add_upload_button(
            "Upload capture",
            icon=viser.Icon.UPLOAD,
            mime_type=UPLOAD_MIME_TYPES,
            hint=f".pcd/.ply point cloud, or a depth image (.png mm, .npy m); at most {MAX_UPLOAD_MB} MB",
        )
        cloud_path: viser.GuiDropdownHandle | None = None
        load_cloud: viser.GuiButtonHandle | None = None
        if data_files is not None:
            cloud_path = gui.add_dropdown(
                "Server file", data_file_options(data_files), hint="A capture file in the server's data folder"
            )
            load_cloud = gui.add_button("Load server file", icon=viser.Icon.FOLDER_OPEN)
    with gui.add_folder("Export", expand_by_default=False):
        export_frame = gui.add_dropdown("Frame", ("world", "camera"), hint="Coordinates of exported points and meshes")
        mesh_format = gui.add_dropdown("Mesh format", MESH_FORMATS)
        export_mesh_kind = gui.add_dropdown("Mesh", MESH_KINDS, hint="Which of the segment's meshes to export")
        export_points = gui.add_button("Segment points (PLY)", icon=viser.Icon.DOWNLOAD)
        export_grids = gui.add_button(
            "CNN grids (NPZ)",
            icon=viser.Icon.DOWNLOAD,
            hint="CNN input, output probabilities, grid frame (grid -> camera metres)",
        )
        export_mesh = gui.add_button("Mesh", icon=viser.Icon.DOWNLOAD, hint="The mesh chosen above")
    return Panel(
        status,
        source,
        seed_h,
        new_scene,
        upload,
        cloud_path,
        load_cloud,
        model,
        model_folder,
        segment,
        complete,
        complete_all,
        revolve,
        fit_boxes,
        detailed,
        partial,
        mirror,
        hull,
        timings,
        layers,
        cloud_colors,
        shade_output,
        sample,
        export_frame,
        mesh_format,
        export_mesh_kind,
        export_points,
        export_grids,
        export_mesh,
    )


def data_file_options(files: tuple[str, ...]) -> tuple[str, ...]:
    """The "Server file" dropdown's entries (a placeholder when the data folder has no capture file)."""
    return files if files else (NO_DATA_FILE,)


def source_markdown(
    source: str,
    n_points: int,
    n_valid: int,
    n_segments: int,
    seg_seconds: float,
    frame_note: str,
    min_height: float | None = None,
) -> str:
    """What was loaded: name, valid/total points, segments (and the table band they were cut above,
    metres; None: no table), segmentation time, which world frame."""
    band = "no table found" if min_height is None else f"cut {min_height * 1000:.0f} mm above the table"
    return (
        f"**{source}**  \n{n_valid:,} valid of {n_points:,} points · **{n_segments}** "
        f"{'segment' if n_segments == 1 else 'segments'}, {band}  \n"
        f"segmentation {seg_seconds * 1000:.0f} ms · {frame_note}"
    )


def model_markdown(arch: str, source: str, trained: bool, meta: dict) -> str:
    """Architecture, weights file, training facts (steps, Jaccard per evaluation set) or a red warning."""
    lines = [f"**{arch}** · weights: `{source}`"]
    if trained:
        facts = [f"{meta['steps']:,} training steps"] if "steps" in meta else []
        if meta.get("averaged_from"):
            facts.append(f"the mean of {len(meta['averaged_from'])} weights files (`shapeviewer average`)")
        jaccard = [
            f"{name.replace('_', ' ')} {v['jaccard']:.2f}"
            for name, v in meta.get("eval", {}).items()
            if isinstance(v, dict) and "jaccard" in v
        ]
        if jaccard:
            facts.append("Jaccard: " + ", ".join(jaccard))
        lines.extend(facts)
    else:
        lines.append('<span style="color:#d32f2f">**⚠ Untrained weights: completions are not meaningful.**</span>')
    return "  \n".join(lines)


def timings_markdown(title: str, rows: list[tuple[str, float]]) -> str:
    """A small table of stage times (seconds) for the last completion."""
    body = "\n".join(f"| {stage} | {seconds * 1000:.1f} ms |" for stage, seconds in rows)
    return f"{title}\n\n| stage | time |\n|---|---:|\n{body}"


def completion_timings(done: list[Completion], seg_seconds: float, send: float) -> dict[str, float]:
    """Seconds per stage of a batch of fast completions (totals over ``done``), with the scene's
    segmentation and the time to send the results to the browser."""
    total = {k: sum(c.timings.get(k, 0.0) for c in done) for k in ("voxelize", "cnn", "priors", "fast_mesh")}
    return {
        "segmentation": seg_seconds,
        "voxelize": total["voxelize"],
        "cnn": total["cnn"],
        "priors": total["priors"],
        "marching_cubes": total["fast_mesh"],
        "send": send,
        "click_to_mesh": sum(total.values()) + send,
    }


def completion_timings_markdown(title: str, timings: dict[str, float]) -> str:
    """The stage table of :func:`completion_timings`."""
    rows = [
        ("segmentation (scene)", timings["segmentation"]),
        ("voxelize", timings["voxelize"]),
        ("CNN", timings["cnn"]),
        ("box fit, axis fit and revolve", timings["priors"]),
        ("marching cubes", timings["marching_cubes"]),
        ("send to browser", timings["send"]),
        ("**click → mesh**", timings["click_to_mesh"]),
    ]
    return timings_markdown(title, rows)


def mesh_timings_markdown(kind: str, segment_id: int, seconds: float, steps: dict[str, float], send: float) -> str:
    """The stage table of a segment's detailed (split by Algorithm 1's ``steps``, seconds) or
    baseline mesh, made in ``seconds`` and sent to the browser in ``send`` seconds."""
    title = f"Segment **{segment_id}**: {MESH_TITLES[kind].lower()}"
    if kind == "detailed":
        title += f" (Algorithm 1, up-sampling r = {steps['upsample_ratio']})"
        rows = [(label, steps[key]) for key, label in ALGORITHM_1_STEPS]
    else:
        rows = [(MESH_TITLES[kind], seconds)]
    rows += [("send to browser", send), ("**total**", seconds + send)]
    return timings_markdown(title, rows)


def confidence_markdown(
    segment_id: int,
    spread_by_side: list[tuple[str, float]],
    guessed: float,
    axis: RevolutionAxis | None = None,
    cuboid: Cuboid | None = None,
) -> str:
    """The confidence of a completion: mean sample spread on each side (seen, unseen) and the share
    of completed voxels that are a guess (see :func:`~shapeviewer.completion.pipeline.confidence_figures`),
    whether it is the box fitted to the points (``cuboid``, :mod:`shapeviewer.completion.cuboid`) and whether its
    answers were revolved about the table's normal (``axis``, :mod:`shapeviewer.completion.revolve`)."""
    text = (
        f"Segment **{segment_id}**: confidence of the completion  \n"
        + " · ".join(f"mean spread {what} side **{v:.3f}**" for what, v in spread_by_side)
        + f"  \n{100 * guessed:.0f}% of the completed voxels are a guess (spread > {GUESS_SPREAD})"
    )
    if cuboid is not None:
        verdict = "completed as the fitted box" if cuboid.accepted else "not a box"
        size = " × ".join(f"{e * 1000:.0f}" for e in cuboid.extents)
        text += (
            f"  \nBox: **{verdict}** ({size} mm; 90% of the points within {cuboid.residual * 1000:.1f} mm of its"
            f" faces, their outline filling {100 * cuboid.fill:.0f}% of its footprint)"
        )
    if axis is not None:
        verdict = "revolved about the table's normal" if axis.accepted else "not revolved"
        text += (
            f"  \nSurface of revolution: **{verdict}** (points within {axis.residual * 1000:.1f} mm of one radius"
            f" of {axis.radius * 1000:.0f} mm per height, seen over {axis.coverage_deg:.0f}° about the axis)"
        )
    return text
