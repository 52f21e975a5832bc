import numpy as np
import pytest

from shapeviewer.completion.reconstruct import EmptyCompletionError, fast_mesh
from shapeviewer.completion.voxel import GridFrame


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


def _rendered_view(mesh, T_cam_obj, seed=0, intr=None, noise=None):
    """Observed points (camera frame) of ``mesh`` posed at ``T_cam_obj``; the Kinect by default."""
    from shapeviewer.perception.camera import Intrinsics, backproject_valid
    from shapeviewer.sim.sensor import KinectNoise, RaycastRenderer

    intr = intr or Intrinsics.kinect()
    depth, _ = RaycastRenderer([mesh]).render(intr, np.linalg.inv(T_cam_obj))
    return backproject_valid((noise or KinectNoise()).apply(depth, seed), intr)


def _box_view(extents, angle, axis, position, seed=0):
    """A box posed in front of the Kinect: ``(box, T_cam_obj, observed points, grid frame)``."""
    import trimesh

    from shapeviewer.completion.voxel import partial_to_grid

    box = trimesh.creation.box(extents)
    T = trimesh.transformations.rotation_matrix(angle, axis)
    T[:3, 3] = position
    pts = _rendered_view(box, T, seed)
    return box, T, pts, partial_to_grid(pts)[1]


def _share_outside(mesh, truth, distance):
    """Share of ``truth``'s surface more than ``distance`` (m) outside ``mesh``."""
    import trimesh

    samples, _ = trimesh.sample.sample_surface(truth, 4000, seed=0)
    return float(np.mean(trimesh.proximity.signed_distance(mesh, samples) < -distance))


def test_detailed_mesh_is_closed_keeps_the_observed_detail_and_fills_the_back():
    import manifold3d
    import trimesh

    from shapeviewer.completion.reconstruct import detailed_mesh
    from shapeviewer.completion.voxel import solid_grid
    from shapeviewer.evaluation.metrics import hausdorff

    box, T, pts, frame = _box_view([0.08, 0.05, 0.06], 0.6, [1, 1, 0], [0.02, -0.01, 0.7])
    # A perfect CNN: the true solid occupancy in the view's grid.
    probs = solid_grid(box, frame, T).astype(np.float32)
    timings = {}
    mesh = detailed_mesh(probs, frame, pts, timings=timings)
    assert mesh.is_watertight
    m = manifold3d.Manifold(
        manifold3d.Mesh(vert_properties=mesh.vertices.astype(np.float32), tri_verts=mesh.faces.astype(np.uint32))
    )
    assert m.status() == manifold3d.Error.NoError
    assert set(timings) >= {"density", "upsample", "merge", "fill_gaps", "smooth", "marching_cubes"}
    truth = box.copy().apply_transform(T)
    assert hausdorff(mesh, truth)["mean_mm"] < 3.0
    # A slightly conservative envelope, as a grasp planner needs: hardly any of the true surface
    # lies more than 1 mm outside it (fingers planned past it would hit the true box early).
    assert _share_outside(mesh, truth, 0.001) < 0.05
    # The observed points lie on the surface (within about one fine voxel, 2 x their spacing).
    d = np.abs(trimesh.proximity.signed_distance(mesh, pts[::20]))
    assert np.median(d) < 0.003
    # And the mesh reaches behind them: its far side is beyond the farthest observed point.
    assert mesh.bounds[1, 2] > pts[:, 2].max() + 0.01


def test_a_dense_close_cloud_merges_at_a_bounded_resolution_and_stays_accurate():
    """A 1280x720 camera 0.3 m from the object: 9 times the Kinect's density at 1 m. The up-sampling
    ratio stops at MAX_UPSAMPLE_RATIO (else a 300^3 merge grid), and the mesh still follows the box."""
    import trimesh

    from shapeviewer.completion.reconstruct import MAX_UPSAMPLE_RATIO, detailed_mesh
    from shapeviewer.completion.voxel import partial_to_grid, solid_fraction, solid_grid
    from shapeviewer.evaluation.metrics import hausdorff
    from shapeviewer.perception.camera import Intrinsics
    from shapeviewer.sim.sensor import RealSenseNoise

    box = trimesh.creation.box([0.16, 0.06, 0.2])
    T = trimesh.transformations.rotation_matrix(0.6, [1, 1, 0])
    T[:3, 3] = [0.0, 0.0, 0.3]
    intr = Intrinsics(1280, 720, 910.0, 910.0, 640.0, 360.0)
    pts = _rendered_view(box, T, intr=intr, noise=RealSenseNoise())
    assert len(pts) > 100_000
    frame = partial_to_grid(pts)[1]
    # A perfect CNN of the shipped kind: how much of each voxel the box fills (the soft label).
    probs = solid_fraction(box, frame, solid_grid(box, frame, T), T).astype(np.float32)
    timings = {}
    mesh = detailed_mesh(probs, frame, pts, timings=timings)
    assert timings["upsample_ratio"] == MAX_UPSAMPLE_RATIO
    assert mesh.is_watertight
    # 1.3 mm here; 1.1 mm with the ratio the density asks for (9), at 35 times the cost.
    assert hausdorff(mesh, box.copy().apply_transform(T))["mean_mm"] < 2.0


def test_detailed_mesh_follows_the_probabilities_between_voxel_centres():
    # A network trained on the soft label says where between two voxel centres the surface lies;
    # the corner vote on thresholded voxels puts it half way, the linear up-sampling keeps it.

    from shapeviewer.completion.reconstruct import detailed_mesh
    from shapeviewer.completion.voxel import solid_fraction, solid_grid
    from shapeviewer.evaluation.metrics import hausdorff

    box, T, pts, frame = _box_view([0.07, 0.05, 0.06], 0.5, [1, 1, 0], [0.01, -0.01, 0.7])
    probs = solid_fraction(box, frame, solid_grid(box, frame, T), T, margin=0.0)
    truth = box.copy().apply_transform(T)
    linear = detailed_mesh(probs, frame, pts, level=0.5, upsample="linear")
    vote = detailed_mesh(probs, frame, pts, level=0.5)
    assert linear.is_watertight and vote.is_watertight
    d_linear, d_vote = hausdorff(linear, truth)["mean_mm"], hausdorff(vote, truth)["mean_mm"]
    assert d_linear < d_vote
    assert abs(linear.volume / truth.volume - 1) < abs(vote.volume / truth.volume - 1)
    # At the up-sampled points themselves: far fewer land on the wrong side of the true surface.
    from shapeviewer.completion.reconstruct import upsample_occupancy, upsample_probabilities
    from shapeviewer.geometry import o3d_tensor, raycasting_scene

    r = 3
    fine = np.argwhere(np.ones((39 * r,) * 3, bool))
    centres = frame.to_metres(fine / r + 0.5 / r + 0.5)
    inside = raycasting_scene(truth).compute_occupancy(o3d_tensor(centres.astype(np.float32))).numpy() > 0
    wrong_linear = np.sum((upsample_probabilities(probs, r) > 0.5).ravel() != inside)
    wrong_vote = np.sum(upsample_occupancy(probs > 0.5, r).ravel() != inside)
    assert wrong_linear < 0.6 * wrong_vote


def test_detailed_mesh_puts_its_visible_side_on_the_observed_points():
    # The union of the merge voxels that noisy points fall in bulges outward; each point marks the
    # voxel a leaf behind it instead, so the seen side of the mesh lies on the points.
    import trimesh

    from shapeviewer.completion.reconstruct import detailed_mesh
    from shapeviewer.completion.voxel import solid_fraction, solid_grid
    from shapeviewer.evaluation.metrics import hausdorff

    box, T, pts, frame = _box_view([0.08, 0.05, 0.06], 0.6, [1, 1, 0], [0.02, -0.01, 0.7])
    probs = solid_fraction(box, frame, solid_grid(box, frame, T), T)
    truth = box.copy().apply_transform(T)
    inset = detailed_mesh(probs, frame, pts, level=0.5)
    voxel_it_falls_in = detailed_mesh(probs, frame, pts, level=0.5, observed_inset=0.0)
    depth = {m: np.median(trimesh.proximity.signed_distance(m, pts[::10])) for m in (inset, voxel_it_falls_in)}
    assert depth[inset] < 0.0015 < depth[voxel_it_falls_in]  # how far inside the mesh the points lie (m)
    assert hausdorff(inset, truth)["mean_mm"] < 0.85 * hausdorff(voxel_it_falls_in, truth)["mean_mm"]
    assert inset.is_watertight


def test_detailed_mesh_keeps_a_thin_plate_whole():
    # A plate 3-4 CNN voxels thick, seen at a slant: the merged grid must not lose its body to
    # rounding or to the half-voxel surface shift.

    from shapeviewer.completion.reconstruct import detailed_mesh
    from shapeviewer.completion.voxel import solid_grid
    from shapeviewer.evaluation.metrics import hausdorff

    plate, T, pts, frame = _box_view([0.10, 0.07, 0.012], 0.9, [1, 0.3, 0], [0.0, 0.02, 0.8], seed=3)
    probs = solid_grid(plate, frame, T).astype(np.float32)
    mesh = detailed_mesh(probs, frame, pts)
    truth = plate.copy().apply_transform(T)
    assert mesh.is_watertight and len(mesh.split(only_watertight=False)) == 1
    assert truth.volume < mesh.volume < 1.6 * truth.volume
    assert _share_outside(mesh, truth, 0.001) < 0.06
    assert hausdorff(mesh, truth)["mean_mm"] < 2.5


def test_a_surface_through_grid_nodes_keeps_its_vertices_apart(tmp_path):
    """A surface through grid nodes would stack the vertices of all their edges on one point, and a
    reader that merges close vertices (trimesh.load) would pinch the closed mesh open."""
    import trimesh
    from scipy.spatial import cKDTree

    from shapeviewer.completion.reconstruct import LEVEL_NUDGE, grid_mesh

    r = np.linalg.norm(np.indices((40, 40, 40)) - 20.0, axis=0).astype(np.float32)
    values = np.float32(5.0) - r + np.float32(0.5 + LEVEL_NUDGE)  # on the level at 6 nodes and more
    mesh = grid_mesh(values, GridFrame(np.zeros(3), 0.003), 0.5)
    assert cKDTree(mesh.vertices).query(mesh.vertices, 2)[0][:, 1].min() > 1e-7
    mesh.export(tmp_path / "sphere.ply")
    assert trimesh.load(tmp_path / "sphere.ply", force="mesh").is_watertight
