"""Grasps with the Barrett BH8-280 and the Franka Panda hand (the paper's Tables IV and V).

- :mod:`shapeviewer.grasp.hands`: hand descriptions (URDF, dofs, coupling, fingers), forward
  kinematics and visual meshes in the palm frame, loading a hand into a pybullet client.
- :mod:`shapeviewer.grasp.world`: :class:`~shapeviewer.grasp.world.GraspWorld`, a pybullet DIRECT
  world with a table, objects and a free-floating hand moved kinematically (approach, close).
- :mod:`shapeviewer.grasp.quality`: GraspIt's epsilon (Ferrari-Canny) and volume qualities.
- :mod:`shapeviewer.grasp.state`: what a grasp is (palm pose, dofs, joints, contacts, qualities).
- :mod:`shapeviewer.grasp.plan`: GraspIt-style planning (:func:`~shapeviewer.grasp.plan.plan`):
  a cheap search (:mod:`~shapeviewer.grasp.search`, on the hand's precomputed
  :mod:`~shapeviewer.grasp.samples` and the object's :mod:`~shapeviewer.grasp.object_field`), then
  the best candidates executed in the pybullet world, then lifted (those that lift the mesh first).
- :mod:`shapeviewer.grasp.execute`: the paper's execution on the true object, joint and pose
  errors.
- :mod:`shapeviewer.grasp.lift`: a dynamic lift test (the planner's lift check, and the
  evaluation's lift of the true object).
- :mod:`shapeviewer.grasp.robust`: each planned grasp re-closed on the CNN's sample completions,
  and the grasps ranked by how well they survive the completion's uncertainty.
- :mod:`shapeviewer.grasp.serialize`: grasps to and from JSON, a pybullet-ready scene zip, headless planning.

Units are metres and radians throughout; frames are named in every docstring.
"""
