"""Grasps in the viewer (paper Fig. 5, step 6; Tables IV and V): plan on a segment's mesh, draw the
hands, execute them on the true object of a synthetic scene, rank them by how many of the
completion's sample completions they hold on (their robustness), export them.

Frames: everything here is in the viewer's WORLD frame (metres, z up, table top z = 0). A segment's
mesh (camera frame on its :class:`~shapeviewer.completion.pipeline.Completion`) is mapped with
``scene.T_world_cam`` before planning; a grasp's ``T_world_palm`` places the palm frame, in which
:func:`~.drawing.hand_solids` gives the hand's palm and fingers.

Jobs: planning, execution and ranking run in a background thread, one grasp job per session at a time,
outside the session's job queue, so the rest of the viewer keeps working meanwhile; they compute
in a small worker pool shared by all sessions. A mesh that the planner needs and the segment lacks
is made first through the session (in its job queue, for the few moments it needs). The
controller reaches the session only through a :class:`GraspHost`.

One module per job: :mod:`.state` (plain values: a segment's grasps, a job, the true object),
:mod:`.summary` (the folder's text), :mod:`.controls` (the folder's GUI), :mod:`.drawing` (scene
nodes, picking), :mod:`.work` (running jobs) and :mod:`.controller`, which ties them together.
"""

from .controller import GraspController, GraspHost
from .drawing import EXECUTED_COLOR, NO_CLOSURE_COLOR, TRUTH_OPACITY, epsilon_colors, hand_skeleton
from .state import GraspJob, SegmentGrasps, ground_truth_object, object_mesh_world

__all__ = [
    "EXECUTED_COLOR",
    "NO_CLOSURE_COLOR",
    "TRUTH_OPACITY",
    "GraspController",
    "GraspHost",
    "GraspJob",
    "SegmentGrasps",
    "epsilon_colors",
    "ground_truth_object",
    "hand_skeleton",
    "object_mesh_world",
]
