import numpy as np
import pytest

from shapeviewer.reconstruct import EmptyCompletionError, fast_mesh
from shapeviewer.voxel import GridFrame


def _sphere_grid(radius, frame, centre):
    idx = np.indices((40, 40, 40)).reshape(3, -1).T
    return (np.linalg.norm(frame.voxel_centers(idx) - centre, axis=1) < radius).reshape(40, 40, 40)


def test_marching_cubes_of_a_voxelized_sphere_is_watertight_with_the_right_volume():
    centre = np.array([0.05, -0.02, 0.9])
    frame = GridFrame(centre, 0.12 / 32)
    occ = _sphere_grid(0.05, frame, centre)
    mesh = fast_mesh(occ.astype(np.float32), frame)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(4 / 3 * np.pi * 0.05**3, rel=0.10)
    # The mesh is in camera metres, around the sphere's centre.
    np.testing.assert_allclose(mesh.bounds.mean(0), centre, atol=frame.voxel_size)


def test_a_blob_touching_the_grid_border_still_closes():
    frame = GridFrame(np.zeros(3), 0.01)
    p = np.zeros((40, 40, 40), np.float32)
    p[:, 10:20, 10:20] = 0.9
    mesh = fast_mesh(p, frame)
    assert mesh.is_watertight


def test_empty_output_is_a_clear_error():
    with pytest.raises(EmptyCompletionError, match="empty"):
        fast_mesh(np.zeros((40, 40, 40), np.float32), GridFrame(np.zeros(3), 0.01))
