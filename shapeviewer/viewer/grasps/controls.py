"""The Grasps folder of the Pipeline tab: its controls (handles only; the controller wires them)."""

from __future__ import annotations

from dataclasses import dataclass

import viser

from ...grasp.hands import HAND_NAMES
from ..gui import ProgressBar
from ..state import MESH_KINDS
from .state import MAX_GRASPS

NO_GRASP = "(none)"
DEFAULT_GRASPS = 20  # the paper plans 20 grasps per object
# The download buttons: format (see GraspController.export) -> label, icon, hint.
EXPORTS = {
    "json": (
        "Grasps (JSON)",
        viser.Icon.DOWNLOAD,
        "Palm poses, joints, contacts, qualities and executions (world frame)",
    ),
    "zip": (
        "pybullet scene (zip)",
        viser.Icon.FILE_ZIP,
        "Object mesh, its convex decomposition and URDF, the hand URDFs, grasps.json",
    ),
}


@dataclass
class GraspPanel:
    """Handles of the Grasps folder."""

    hand: viser.GuiDropdownHandle
    method: viser.GuiDropdownHandle
    count: viser.GuiNumberHandle
    plan: viser.GuiButtonHandle
    progress: ProgressBar
    cancel: viser.GuiButtonHandle
    rank: viser.GuiButtonHandle  # enabled while the listed segment has grasps and no job runs
    grasp: viser.GuiDropdownHandle
    show_all: viser.GuiCheckboxHandle
    info: viser.GuiMarkdownHandle
    execute: viser.GuiButtonHandle
    execute_all: viser.GuiButtonHandle
    exports: dict[str, viser.GuiButtonHandle]  # format -> its download button

    @property
    def job_buttons(self) -> tuple[viser.GuiButtonHandle, ...]:
        """Buttons that start a grasp job whenever none runs (Rank by robustness also needs grasps)."""
        return (self.plan, self.execute, self.execute_all)


def build_grasp_panel(gui: viser.GuiApi, order: float | None = None) -> GraspPanel:
    """Add the Grasps folder to ``gui`` (at ``order`` among the top-level folders)."""
    with gui.add_folder("Grasps", order=order):
        hand = gui.add_dropdown("Hand", HAND_NAMES, hint="Barrett BH8-280 (the paper's) or the Franka Panda gripper")
        method = gui.add_dropdown(
            "Plan on", MESH_KINDS, hint="Which mesh of the selected segment to plan on (made first if missing)"
        )
        count = gui.add_number(
            "Grasps",
            DEFAULT_GRASPS,
            min=1,
            max=MAX_GRASPS,
            step=1,
            hint="How many distinct grasps to keep (the paper: 20)",
        )
        plan_b = gui.add_button(
            "Plan grasps",
            icon=viser.Icon.HAND_GRAB,
            hint="Plan grasps on the selected segment's mesh (a few seconds, in the background)",
        )
        progress = gui.add_progress_bar(0.0, visible=False, animated=True)
        cancel = gui.add_button(
            "Cancel", icon=viser.Icon.PLAYER_STOP, color="red", disabled=True, hint="Stop the running grasp job"
        )
        rank = gui.add_button(
            "Rank by robustness",
            icon=viser.Icon.SHIELD_CHECK,
            disabled=True,
            hint="Re-close every grasp on 8 sample completions (other plausible shapes of the unseen side), "
            "the hand a few mm off on each, lift the most robust on them, and list the grasps that lift "
            "and hold most of them first; when none lifts most of them, as many again are planned on the "
            "grasp envelope and ranked with them",
        )
        grasp = gui.add_dropdown("Grasp", (NO_GRASP,), hint="Select a grasp: it is highlighted and described below")
        show_all = gui.add_checkbox("Show all", True, hint="Show the other grasps dimmed (off: only the selected one)")
        info = gui.add_markdown("_Select a segment, then plan grasps on it._")
        execute = gui.add_button(
            "Execute on ground truth",
            icon=viser.Icon.PLAYER_PLAY,
            hint="Run the selected grasp on the true object (synthetic scenes): approach, close, lift",
        )
        execute_all = gui.add_button(
            "Execute all", icon=viser.Icon.LIST_CHECK, hint="Run every grasp of this segment on the true object"
        )
        exports = {fmt: gui.add_button(label, icon=icon, hint=hint) for fmt, (label, icon, hint) in EXPORTS.items()}
    return GraspPanel(
        hand, method, count, plan_b, progress, cancel, rank, grasp, show_all, info, execute, execute_all, exports
    )
