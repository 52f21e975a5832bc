"""shapeviewer: Shape Completion Enabled Robotic Grasping (Varley et al., IROS 2017), runnable and visible."""

import os

# OpenMP threads that spin while they wait make a 2-thread CNN pass 10-20x slower (about 0.3 s
# instead of 20 ms) as soon as anything else runs on a 2-core machine. Sleeping waits keep clicks
# fast under load. Only effective before torch is first imported, hence here.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
