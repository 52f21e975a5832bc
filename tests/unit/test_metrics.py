import numpy as np
import pytest
import trimesh

from shapeviewer.evaluation.metrics import completion_metrics, geodesic_divergence, hausdorff, jaccard

# Objects sit in front of a camera, as the evaluation's meshes do (camera frame, metres).
WHERE = np.array([0.05, -0.03, 0.8])


def _sphere(radius, subdivisions=4):
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    mesh.apply_translation(WHERE)
    return mesh


def _box(extents, shift=(0.0, 0.0, 0.0)):
    mesh = trimesh.creation.box(extents)
    mesh.apply_translation(WHERE + np.asarray(shift))
    return mesh


@pytest.fixture(scope="module")
def sphere():
    return _sphere(0.05)


def test_identical_meshes_score_perfectly(sphere):
    other = sphere.copy()
    assert jaccard(sphere, other) == 1.0
    h = hausdorff(sphere, other)
    assert h["mean_mm"] < 1e-3 and h["max_mm"] < 1e-2 and h["rms_mm"] < 1e-3
    assert geodesic_divergence(sphere, other) < 1e-9


def test_concentric_spheres_hausdorff_is_difference_of_radii(sphere):
    h = hausdorff(sphere, _sphere(0.06))
    # Facets put an icosphere's triangles at most 0.1% of the radius inside the sphere.
    for key in ("mean_mm", "max_mm", "rms_mm"):
        assert h[key] == pytest.approx(10.0, rel=0.02)


def test_translated_cube_jaccard_matches_analytic_overlap():
    cube = _box((0.1, 0.1, 0.1))
    # 10 cm cubes 1 cm apart overlap in 9 cm of 11 cm.
    assert jaccard(cube, _box((0.1, 0.1, 0.1), (0.01, 0, 0))) == pytest.approx(9 / 11, rel=0.02)


def test_jaccard_counts_every_voxel_a_solid_touches():
    # 10 cm cubes 3 cm apart: the common box is a 13 cm cube, 1.625 mm voxels. Along x the cubes
    # touch voxels 0..61 and 18..79 (overlap 18..61), along y and z the same 62 voxels: 44 / 80.
    # That is 2% above the exact 7/13 because touched voxels count whole.
    score = jaccard(_box((0.1, 0.1, 0.1)), _box((0.1, 0.1, 0.1), (0.03, 0, 0)))
    assert score == pytest.approx(44 / 80, abs=1e-12)
    assert score == pytest.approx(7 / 13, rel=0.025)


@pytest.mark.parametrize(
    "solid, volume",
    [
        (_sphere(0.05), 4 / 3 * np.pi * 0.05**3),
        # Non-convex with a hole: columns cross its surface up to four times.
        (trimesh.creation.torus(0.04, 0.015, major_sections=64, minor_sections=32), 2 * np.pi**2 * 0.04 * 0.015**2),
    ],
)
def test_interior_is_filled_exactly(solid, volume):
    # Inside a box that fills the common box, the index is the solid's voxelized volume over the box's.
    solid = solid.copy()
    solid.apply_translation(WHERE - solid.bounds.mean(axis=0))
    side = 0.12
    score = jaccard(solid, _box((side, side, side)))
    voxel = side / 80
    surface_layer = solid.area * np.sqrt(3) * voxel  # touched voxels reach at most a diagonal out
    assert 0.99 * volume / side**3 < score < (volume + surface_layer) / side**3


def test_metrics_are_symmetric(sphere):
    box = _box((0.04, 0.06, 0.12), (0.02, 0, 0))
    assert jaccard(sphere, box) == jaccard(box, sphere)
    ab, ba = hausdorff(sphere, box), hausdorff(box, sphere)
    for key in ab:
        assert ab[key] == pytest.approx(ba[key], rel=1e-9)
    assert geodesic_divergence(sphere, box) == pytest.approx(geodesic_divergence(box, sphere), abs=1e-9)


def test_geodesic_divergence_separates_shapes(sphere):
    long_thin_box = _box((0.02, 0.02, 0.3)).subdivide_to_size(0.005)
    scaled = sphere.copy()
    scaled.apply_scale(1.02)
    different = geodesic_divergence(sphere, long_thin_box)
    similar = geodesic_divergence(sphere, scaled)
    # Sphere against scaled sphere: 0.11; against the box: 0.87 (0.69 and 0.73 with seeds 1, 2).
    assert 0.0 <= similar < 0.2 and 0.5 < different <= 1.0


def test_geodesic_divergence_ignores_pose(sphere):
    moved = sphere.copy()
    moved.apply_transform(trimesh.transformations.random_rotation_matrix(np.random.default_rng(3).random(3)))
    moved.apply_translation([0.3, 0.1, -0.2])
    assert geodesic_divergence(sphere, moved) < 1e-6


def test_same_seed_same_result(sphere):
    box = _box((0.04, 0.06, 0.12), (0.02, 0, 0)).subdivide_to_size(0.01)
    assert jaccard(sphere, box) == jaccard(sphere, box)
    assert hausdorff(sphere, box, seed=5) == hausdorff(sphere, box, seed=5)
    assert hausdorff(sphere, box, seed=5) != hausdorff(sphere, box, seed=6)
    assert geodesic_divergence(sphere, box, seed=5) == geodesic_divergence(sphere, box, seed=5)
    assert geodesic_divergence(sphere, box, seed=5) != geodesic_divergence(sphere, box, seed=6)


def test_open_meshes(sphere):
    open_sphere = sphere.copy()
    open_sphere.update_faces(np.arange(len(sphere.faces)) >= 40)
    assert not open_sphere.is_watertight
    with pytest.raises(ValueError, match="not watertight"):
        jaccard(open_sphere, sphere)
    # Surface voxels only: a thin shell against the full ball.
    assert 0.05 < jaccard(open_sphere, sphere, allow_open=True) < 0.5
    assert hausdorff(open_sphere, sphere)["mean_mm"] < 0.5
    # Still a sphere's distribution of geodesics, unlike a long thin box's: 0.07-0.15 against the
    # full sphere and 0.60-0.86 against the box for seeds 0-4.
    long_thin_box = _box((0.02, 0.02, 0.3)).subdivide_to_size(0.005)
    assert geodesic_divergence(open_sphere, sphere) < 0.25 < geodesic_divergence(open_sphere, long_thin_box)


def test_completion_metrics_reports_all_three(sphere):
    result = completion_metrics(_sphere(0.06), sphere)
    assert set(result) == {"jaccard", "j80", "hausdorff_mean_mm", "hausdorff_max_mm", "hausdorff_rms_mm", "geodesic"}
    assert result["j80"] == pytest.approx((5 / 6) ** 3, abs=0.02)  # plain volume overlap, no touched layer
    assert result["hausdorff_mean_mm"] == pytest.approx(10.0, rel=0.02)
    assert 0.5 < result["jaccard"] < 0.65  # (5/6)^3 = 0.579 plus the touched-voxel layer
