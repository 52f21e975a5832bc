"""Shape completion: the 40^3 voxel grid, the CNN, meshing (Algorithm 1), baselines and shape priors."""
