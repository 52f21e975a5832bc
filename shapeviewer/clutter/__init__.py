"""The simulated clutter-removal benchmark of VGN (Breyer et al., CoRL 2020) and GIGA (Jiang et al., RSS 2021).

A free-floating Franka Panda hand clears piles or packed rows of objects from a table, one grasp
per side-view depth capture, and each method is scored by its grasp success rate (GSR) and the
share of objects it cleared (declutter rate, DR). The modules:

- :mod:`.scene`: the pybullet world (table, workspace, object sets) and the pile / packed scenes;
- :mod:`.sensor`: the side-view depth camera and the "dex" depth noise, as a :class:`Capture`;
- :mod:`.execute`: the grasp execution protocol (pre-grasp, approach, close, lift) and its outcomes;
- :mod:`.methods`: the methods that pick a grasp from a capture (``Highest``) and their interface;
- :mod:`.run`: rounds, seeds, the resumable output folder and the summary (:func:`.run.clear_table`).

Frames: the benchmark's world frame has the workspace cube [0, 0.3]^3 m with the table top at
z = :data:`.scene.TABLE_Z` (not at z = 0 like the planner's world), +z up. Units: metres, radians, seconds.
"""
