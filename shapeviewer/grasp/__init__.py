"""Grasps with the Barrett BH8-280 and the Franka Panda hand (SPEC section 8).

- :mod:`shapeviewer.grasp.hands`: hand descriptions (URDF, dofs, coupling, fingers), forward
  kinematics and visual meshes in the palm frame, loading a hand into a pybullet client.
- :mod:`shapeviewer.grasp.world`: :class:`~shapeviewer.grasp.world.GraspWorld`, a pybullet DIRECT
  world with a table, objects and a free-floating hand moved kinematically (approach, close).
- :mod:`shapeviewer.grasp.quality`: GraspIt's epsilon (Ferrari-Canny) and volume qualities.
- :mod:`shapeviewer.grasp.plan`: GraspIt-style planning (:func:`~shapeviewer.grasp.plan.plan_grasps`).
- :mod:`shapeviewer.grasp.execute`: the paper's execution on the true object, joint and pose
  errors, and a dynamic lift test.
- :mod:`shapeviewer.grasp.serialize`: grasps to and from JSON, a pybullet-ready scene zip, headless planning.

Units are metres and radians throughout; frames are named in every docstring.
"""
