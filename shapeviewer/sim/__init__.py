"""The simulated side of the system: the object catalogue, procedural household shapes, the app's demo
scene and tabletop views. Training data (:mod:`shapeviewer.training.generate`) and the evaluation's test
views are rendered from these."""
