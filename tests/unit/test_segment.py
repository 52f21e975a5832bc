"""Segmentation (paper Fig. 5, step 2): plane removal and Euclidean clustering, synthetic and real."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from shapeviewer.perception.camera import look_at, transform_points
from shapeviewer.perception.capture import Capture, load_capture
from shapeviewer.perception.segment import (
    MIN_HEIGHT,
    SegmentationError,
    flying_pixels,
    isolate,
    segment_scene,
    table_band,
    table_frame,
)

SPACING = 0.005  # m between synthetic surface samples


def _box(centre_xy, size) -> np.ndarray:
    """World points (m) on the sides and top of a box standing on z = 0.

    Heights are sampled at 2.5 mm + k * 5 mm, so none lies near a height cut of 5, 10 or 15 mm.
    """
    (cx, cy), (sx, sy, sz) = centre_xy, size
    zs = np.arange(SPACING / 2, sz, SPACING)
    pts = []
    for along, n in ((np.arange(-sx / 2, sx / 2, SPACING), "x"), (np.arange(-sy / 2, sy / 2, SPACING), "y")):
        a, z = np.meshgrid(along, zs)
        for side in (-1, 1):
            if n == "x":
                pts.append(np.stack([cx + a, np.full_like(a, cy + side * sy / 2), z], -1).reshape(-1, 3))
            else:
                pts.append(np.stack([np.full_like(a, cx + side * sx / 2), cy + a, z], -1).reshape(-1, 3))
    gx, gy = np.meshgrid(np.arange(-sx / 2, sx / 2, SPACING), np.arange(-sy / 2, sy / 2, SPACING))
    pts.append(np.stack([cx + gx, cy + gy, np.full_like(gx, zs[-1])], -1).reshape(-1, 3))
    return np.concatenate(pts)


def _cylinder(centre_xy, radius: float, height: float) -> np.ndarray:
    angles = np.arange(0, 2 * np.pi, SPACING / radius)
    a, z = np.meshgrid(angles, np.arange(SPACING / 2, height, SPACING))
    return np.stack([centre_xy[0] + radius * np.cos(a), centre_xy[1] + radius * np.sin(a), z], -1).reshape(-1, 3)


def _scene(extra: list[np.ndarray] = (), seed: int = 0, table_noise: float = 0.001):
    """A 1.2 m table with Gaussian height noise ``table_noise`` (m) and three objects (and ``extra``
    world point sets) on it, seen from above.

    Returns ``(camera-frame points with NaN rows, truth label per row, T_world_cam)``; labels are
    -2 for NaN rows, -1 for the table, k for the k-th object (left to right), 3+ for ``extra``.
    """
    rng = np.random.default_rng(seed)
    gx, gy = np.meshgrid(np.arange(-0.6, 0.6, SPACING), np.arange(-0.6, 0.6, SPACING))
    table = np.stack([gx.ravel(), gy.ravel(), rng.normal(0, table_noise, gx.size)], -1)
    objects = [
        _box((-0.25, 0.1), (0.08, 0.06, 0.12)),
        _cylinder((0.0, 0.0), 0.04, 0.15),
        _box((0.25, -0.1), (0.05, 0.05, 0.05)),
        *extra,
    ]
    world = np.concatenate([table, *objects, np.full((500, 3), np.nan)])
    labels = np.concatenate(
        [np.full(len(table), -1)] + [np.full(len(o), k) for k, o in enumerate(objects)] + [np.full(500, -2)]
    )
    T_world_cam = look_at(np.array([0.0, -0.8, 0.7]), np.zeros(3))
    order = rng.permutation(len(world))  # segment indices must survive any row order
    points = transform_points(np.linalg.inv(T_world_cam), world[order])
    return points, labels[order], T_world_cam


def test_synthetic_scene_gives_one_segment_per_object() -> None:
    points, truth, T_true = _scene()
    seg = segment_scene(points)
    assert len(seg.segments) == 3
    # numbered nearest first: the small box (nearest the camera), the cylinder, the tall box
    distances = [float(np.linalg.norm(s.points_cam.mean(axis=0))) for s in seg.segments]
    assert distances == sorted(distances)
    for i, (k, s) in enumerate(zip([2, 1, 0], seg.segments)):
        world_z = transform_points(T_true, points[truth == k])[:, 2]
        expected = np.flatnonzero(truth == k)[world_z >= MIN_HEIGHT]  # a quiet table: the lowest band
        np.testing.assert_array_equal(np.sort(s.indices), expected)
        np.testing.assert_array_equal(s.points_cam, points[s.indices])
        assert re.fullmatch(rf"segment {i} \({len(expected)} pts, \d+ cm\)", s.label)
    assert len({tuple(s.color) for s in seg.segments}) == 3
    # The estimated table frame: the table at z = 0, the camera 0.7 m above it, x along the camera's x.
    table_world = transform_points(seg.T_world_cam, points[truth == -1])
    assert np.abs(table_world[:, 2]).max() < 0.005
    assert seg.T_world_cam[2, 3] == pytest.approx(0.7, abs=0.002)
    assert seg.T_world_cam[0, 0] > 0.99
    np.testing.assert_allclose(seg.plane_cam[:3] @ points[truth == -1].T + seg.plane_cam[3], 0, atol=0.005)
    world_z = np.full(len(points), np.nan)
    world_z[truth > -2] = transform_points(T_true, points[truth > -2])[:, 2]
    assert np.abs(world_z[seg.table_indices]).max() < 0.012  # the table and the objects' bottom 1 cm
    assert len(seg.table_indices) > 0.99 * (truth == -1).sum()
    assert set(seg.timings) == {"prepare", "plane", "downsample", "cluster", "segments", "total"}


def test_the_height_band_follows_the_tables_noise() -> None:
    """Over a noisier table the band rises (3.5 sigma, within 5..15 mm), so no table point joins a
    segment, and a quiet table leaves every object its points down to 5 mm."""
    for sigma, band in ((0.0005, 0.005), (0.002, 0.007), (0.003, 0.0105)):
        points, truth, T_true = _scene(seed=1, table_noise=sigma)
        heights = transform_points(T_true, np.nan_to_num(points))[:, 2][truth > -2]
        assert table_band(heights) == pytest.approx(band, abs=0.0006)
        seg = segment_scene(points)
        assert len(seg.segments) == 3
        assert seg.min_height == pytest.approx(band, abs=0.0006)  # the band the viewer reports
        in_segments = np.concatenate([s.indices for s in seg.segments])
        assert (truth[in_segments] >= 0).all()  # not one table point
        world_z = transform_points(T_true, points[in_segments])[:, 2]
        assert world_z.min() == pytest.approx(0.0025 + 0.005 * np.ceil((band - 0.0025) / 0.005), abs=1e-6)
    assert table_band(np.random.default_rng(0).normal(0, 0.008, 1000)) == 0.015  # the highest band
    assert table_band(np.full(100, 0.01)) == MIN_HEIGHT  # nothing under the plane: no table among the points


def test_size_filters_and_height_band() -> None:
    wall = _box((0.0, 0.4), (0.8, 0.02, 0.2))  # longer than max_extent
    crumb = _box((-0.4, -0.3), (0.02, 0.02, 0.03))  # fewer than min_points
    balloon = _box((0.4, 0.3), (0.05, 0.05, 0.05)) + [0, 0, 0.7]  # floats above max_height
    points, truth, _ = _scene([wall, crumb, balloon])
    assert (truth == 4).sum() < 200
    seg = segment_scene(points)
    assert len(seg.segments) == 3
    assert not set(np.concatenate([s.indices for s in seg.segments])) & set(np.flatnonzero(truth >= 3))
    assert len(segment_scene(points, max_extent=1.0).segments) == 4  # the wall is back
    assert len(segment_scene(points, min_points=20).segments) == 4  # the crumb is back


def test_isolate_cuts_one_object_as_the_segmentation_would() -> None:
    """A mask-like selection of the cylinder (its points, the table ring around its foot, stray
    depth pixels 30 cm behind it) keeps exactly the cylinder's points above the band (a quiet table: the lowest)."""
    points, labels, T_world_cam = _scene()
    world = transform_points(T_world_cam, np.nan_to_num(points))
    near_foot = (labels == -1) & (np.hypot(world[:, 0], world[:, 1]) < 0.06)
    cylinder, ring = points[labels == 1], points[near_foot]
    stray = transform_points(np.linalg.inv(T_world_cam), np.array([[0.0, 0.3, 0.05], [0.01, 0.31, 0.06]]))
    mask = np.concatenate([cylinder, ring, stray, np.full((3, 3), np.nan)])
    plane_cam = T_world_cam.T @ np.array([0.0, 0.0, 1.0, 0.0])  # the table z = 0, normal up
    kept = isolate(mask, support_plane=plane_cam)
    expected = np.zeros(len(mask), bool)
    expected[: len(cylinder)] = world[labels == 1][:, 2] >= MIN_HEIGHT
    assert np.array_equal(kept, expected)
    # Without a plane nothing is cut by height; the largest cluster (cylinder and ring) still drops
    # the strays and the NaNs.
    assert np.array_equal(isolate(mask), np.arange(len(mask)) < len(cylinder) + len(ring))
    # A flat object (a plate lying in the band) keeps all its finite points.
    assert isolate(ring, support_plane=plane_cam).all()


def test_isolate_keeps_the_parts_of_one_object_whose_connection_was_not_seen() -> None:
    """A dumbbell whose bar the camera missed (two weights 6 cm apart) keeps both weights; a crumb
    beside it (a few stray points) and a smaller object 20 cm away (a neighbour in a detector's box)
    are dropped."""
    weights = [_box((-0.05, 0.0), (0.04, 0.08, 0.08)), _box((0.05, 0.0), (0.04, 0.08, 0.08))]
    crumb = _box((0.0, 0.08), (0.01, 0.01, 0.01))
    neighbour = _box((0.3, 0.0), (0.05, 0.05, 0.06))
    mask = np.concatenate([*weights, crumb, neighbour])
    kept = isolate(mask)
    n = len(weights[0]) + len(weights[1])
    assert kept[:n].all() and not kept[n:].any()
    # One weight alone is still one object.
    assert isolate(weights[0]).all()


def test_flying_pixels_are_the_stray_points_behind_a_silhouette() -> None:
    """A box face seen at 1 m (2 mm pixels) with a one-pixel-wide handle, and 40 silhouette pixels
    that took depths between the face and the wall 30 cm behind it: exactly those 40 are flagged."""
    rng = np.random.default_rng(0)
    u, v = np.meshgrid(np.arange(-0.05, 0.05, 0.002), np.arange(-0.05, 0.05, 0.002))
    face = np.stack([u.ravel(), v.ravel(), np.full(u.size, 1.0)], -1)
    handle = np.stack([np.full(15, 0.052), np.arange(15) * 0.002 - 0.015, np.full(15, 1.0)], -1)
    edge = face[np.isclose(face[:, 0], face[:, 0].min())]
    depth = rng.uniform(1.02, 1.3, len(edge))[:40]
    flying = edge[:40] * depth[:, None]  # along each edge pixel's ray, behind the face
    points = np.concatenate([face, handle, flying])
    expected = np.arange(len(points)) >= len(face) + len(handle)
    assert np.array_equal(flying_pixels(points), expected)
    assert not flying_pixels(face).any() and not flying_pixels(np.zeros((3, 3))).any()


def test_flying_pixels_do_not_join_an_object_to_its_neighbour_behind() -> None:
    """A box face at 0.70 m and a neighbour's face at 0.76 m beside it in the image (2 mm pixels):
    the front face's edge pixels took depths between the two, a sparse sheet that bridges the 6 cm
    gap closer than the clustering tolerance. Two segments, each without those pixels."""
    rng = np.random.default_rng(0)
    u, v = np.meshgrid(np.arange(-0.06, 0.0, 0.002), np.arange(-0.05, 0.05, 0.002))
    front = np.stack([u.ravel(), v.ravel(), np.full(u.size, 0.70)], -1)
    back = np.stack([-u.ravel() + 0.002, v.ravel(), np.full(u.size, 0.76)], -1)
    rows = np.arange(-0.05, 0.05, 0.002)
    flying = np.stack([np.zeros(len(rows)), rows, rng.uniform(0.705, 0.755, len(rows))], -1)
    seg = segment_scene(np.concatenate([front, back, flying]))
    assert sorted(len(s.indices) for s in seg.segments) == [len(front), len(back)]
    assert {int(s.indices.min()) for s in seg.segments} == {0, len(front)}


def test_table_frame_is_a_rigid_table_aligned_frame() -> None:
    n = np.array([0.1, -0.8, -0.5])
    n /= np.linalg.norm(n)
    T = table_frame(np.append(n, 0.9))
    R = T[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(T[:3, 3], [0, 0, 0.9], atol=1e-12)  # the camera, 0.9 m up
    np.testing.assert_allclose(R @ n, [0, 0, 1], atol=1e-12)  # the normal is world up
    foot = -0.9 * n + 0.3 * np.cross(n, [1, 0, 0])  # any point on the plane lands at z = 0
    assert transform_points(T, foot[None])[0, 2] == pytest.approx(0.0, abs=1e-12)


def test_no_support_plane_clusters_everything() -> None:
    cube = _box((0.0, 0.0), (0.2, 0.2, 0.2)) + [0, 0, 0.8]  # six planar faces, none table-sized
    seg = segment_scene(cube)
    assert seg.plane_cam is None and len(seg.table_indices) == 0
    np.testing.assert_array_equal(seg.T_world_cam, np.eye(4))
    assert len(seg.segments) == 1 and len(seg.segments[0].indices) == len(cube)


def test_determinism() -> None:
    points, _, _ = _scene(seed=3)
    a, b = segment_scene(points, seed=7), segment_scene(points, seed=7)
    np.testing.assert_array_equal(a.plane_cam, b.plane_cam)
    np.testing.assert_array_equal(a.table_indices, b.table_indices)
    assert [s.indices.tolist() for s in a.segments] == [s.indices.tolist() for s in b.segments]


@pytest.mark.parametrize(
    "points, message",
    [
        (np.zeros((0, 3)), "empty"),
        (np.full((100, 3), np.nan), "no finite points"),
        (np.zeros((10, 2)), r"shape \(N, 3\)"),
        ([["a", "b", "c"]], "not an array of numbers"),
        (np.tile([0.0, 0.0, -1.0], (50, 1)), "in front of the camera"),
    ],
)
def test_unusable_input_raises(points, message: str) -> None:
    with pytest.raises(SegmentationError, match=message):
        segment_scene(points)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"voxel_size": 0.0}, "voxel_size"),
        ({"cluster_tolerance": 0.005, "voxel_size": 0.01}, "at least voxel_size"),
        ({"min_height": 0.2, "max_height": 0.1}, "min_height"),
    ],
)
def test_bad_parameters_raise(kwargs: dict, message: str) -> None:
    with pytest.raises(SegmentationError, match=message):
        segment_scene(_box((0, 0), (0.1, 0.1, 0.1)) + [0, 0, 1], **kwargs)


@pytest.mark.parametrize("n", [1, 2, 3, 50])
def test_too_few_points_give_no_segments(n: int) -> None:
    pts = np.random.default_rng(0).uniform(-0.1, 0.1, (n, 3)) + [0, 0, 1]
    assert segment_scene(pts).segments == []


# ---------------------------------------------------------------------------------------------
# Real captures (PCL test data, ../shared/data/real)


def _pixel_boxes(seg, width: int = 640):
    """(row min, row max, col min, col max) of every segment's pixels."""
    out = []
    for s in seg.segments:
        r, c = np.divmod(s.indices, width)
        out.append((r.min(), r.max(), c.min(), c.max()))
    return out


def _segments_inside(seg, box, min_points: int) -> list:
    r0, r1, c0, c1 = box
    return [
        s
        for s, (a, b, c, d) in zip(seg.segments, _pixel_boxes(seg))
        if len(s.indices) >= min_points and a >= r0 and b <= r1 and c >= c0 and d <= c1
    ]


@pytest.fixture(scope="module")
def milk_clorox(real_data: Path) -> Capture:
    return load_capture(real_data / "milk_cartoon_all_small_clorox.pcd")


def test_milk_clorox_floor_removed_and_objects_whole(milk_clorox: Capture) -> None:
    seg = segment_scene(milk_clorox)
    assert -seg.plane_cam[1] > 0.7  # the floor, seen from above
    assert len(seg.table_indices) > 150_000
    # detergent, milk carton, bleach bottle (handle included): one segment each. The fourth object
    # (bottom-left) is closer than the Kinect's minimum range and has no depth at all.
    for box in [(130, 310, 60, 220), (50, 240, 220, 340), (55, 270, 390, 515)]:
        [obj] = _segments_inside(seg, box, 5000)
        assert 0.15 < obj.extent.max() < 0.30
    for s in seg.segments:
        assert 0.05 <= s.extent.max() <= (0.35 if s.centroid[2] < 1.4 else 0.5), s.label
    # Only the three objects: the legs and casters of the office chair at the top edge, 1.5-2 m away,
    # are outside the workspace (object_range); numbered nearest first.
    assert len(seg.segments) == 3
    distances = [float(np.linalg.norm(s.centroid)) for s in seg.segments]
    assert distances == sorted(distances) and distances[-1] < 1.5
    # Without the workspace they come back: small fragments (a leg with its caster is up to 46 cm
    # long: the flying pixels that made it longer are gone), all far away at the top of the image.
    everything = segment_scene(milk_clorox, object_range=None)
    others = [s for s in everything.segments if len(s.indices) < 5000]
    assert len(everything.segments) == 3 + len(others) and len(others) >= 4
    boxes = _pixel_boxes(everything)
    assert all(box[0] < 80 and s.centroid[2] > 1.4 for s, box in zip(everything.segments, boxes) if s in others)


def test_milk_clorox_is_deterministic(milk_clorox: Capture) -> None:
    a, b = segment_scene(milk_clorox, seed=1), segment_scene(milk_clorox, seed=1)
    np.testing.assert_array_equal(a.plane_cam, b.plane_cam)
    assert [s.indices.tolist() for s in a.segments] == [s.indices.tolist() for s in b.segments]


def test_mug_is_one_segment(real_data: Path) -> None:
    seg = segment_scene(load_capture(real_data / "table_scene_mug_stereo_textured.pcd"))
    [mug] = _segments_inside(seg, (200, 400, 290, 520), 5000)
    assert 0.08 < mug.extent.max() < 0.18
    assert [s for s in seg.segments if len(s.indices) >= 5000] == [mug]


def test_laptop_and_tissue_box(real_data: Path) -> None:
    seg = segment_scene(load_capture(real_data / "frame_20121214T142255.814212.pcd"))
    [laptop] = _segments_inside(seg, (130, 340, 110, 400), 5000)
    [tissues] = _segments_inside(seg, (160, 330, 360, 520), 5000)
    assert laptop.extent.max() == pytest.approx(0.38, abs=0.05)
    assert tissues.extent.max() == pytest.approx(0.24, abs=0.05)


def test_segmented_milk_carton_without_plane(real_data: Path) -> None:
    capture = load_capture(real_data / "milk.pcd")
    seg = segment_scene(capture)
    assert seg.plane_cam is None
    np.testing.assert_array_equal(seg.T_world_cam, np.eye(4))
    [carton] = seg.segments
    # The cloud is the carton: all of its 13,704 points but about 1 % of sparse silhouette pixels.
    points = capture.flat_points()[capture.valid_mask().reshape(-1)]
    assert len(carton.indices) == 13704 - flying_pixels(points).sum() > 13500
    assert 0.2 < carton.extent.max() < 0.3
