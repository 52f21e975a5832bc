"""Capture loaders: real PCL captures, hand-written PCD/PLY variants, depth images and broken files."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from shapeviewer.perception.camera import Intrinsics, backproject
from shapeviewer.perception.capture import CaptureError, fit_intrinsics, load_capture, load_cloud, load_depth

# file -> (organized shape, finite points, (fx, fy, cx, cy) or None, has colours); numbers from the README
REAL = {
    "milk_cartoon_all_small_clorox.pcd": ((480, 640), 241407, (525.0, 525.0, 319.5, 239.5), True),
    "table_scene_mug_stereo_textured.pcd": ((480, 640), 209280, (964.4, 964.4, 319.8, 223.4), True),
    "frame_20121214T142255.814212.pcd": ((480, 640), 271575, (525.0, 525.0, 320.0, 240.0), True),
    "milk.pcd": (None, 13704, None, False),
}


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_captures(real_data: Path, name: str) -> None:
    shape, n_finite, intr, has_colors = REAL[name]
    cap = load_capture(real_data / name)
    assert cap.source == str(real_data / name)
    assert cap.organized == (shape is not None)
    assert cap.points_cam.shape == ((*shape, 3) if shape else (n_finite, 3))
    assert int(cap.valid_mask().sum()) == n_finite
    valid = cap.flat_points()[cap.valid_mask()]
    assert 0.4 < valid[:, 2].min() and valid[:, 2].max() < 3.0  # metres in front of the camera
    if has_colors:
        assert cap.colors.dtype == np.uint8 and cap.colors.shape == cap.points_cam.shape
        assert cap.flat_colors()[cap.valid_mask()].std() > 10  # real colours, not a constant
    else:
        assert cap.colors is None
    if intr is None:
        assert cap.intrinsics is None
    else:
        got = cap.intrinsics
        assert (got.width, got.height) == (640, 480)
        np.testing.assert_allclose((got.fx, got.fy, got.cx, got.cy), intr, atol=0.1)


def test_given_intrinsics_are_kept_and_checked(real_data: Path) -> None:
    k = Intrinsics.kinect()
    assert load_cloud(real_data / "milk_cartoon_all_small_clorox.pcd", k).intrinsics == k
    with pytest.raises(CaptureError, match="milk_cartoon_all_small_clorox.pcd.*320x240"):
        load_cloud(real_data / "milk_cartoon_all_small_clorox.pcd", Intrinsics(320, 240, 262.5, 262.5, 159.5, 119.5))


# ---------------------------------------------------------------------------------------------
# Hand-written files: every encoding, organized, with NaN rows and packed colours.


def _grid_cloud() -> tuple[Intrinsics, np.ndarray, np.ndarray]:
    """A 6x5 organized cloud of a tilted plane (two NaN pixels) and its colours."""
    intr = Intrinsics(6, 5, 5.0, 5.5, 2.5, 2.0)
    v, u = np.mgrid[0:5, 0:6]
    depth = (1.0 + 0.05 * u + 0.02 * v).astype(np.float32)
    depth[1, 2] = depth[3, 4] = 0.0
    points = backproject(depth, intr).astype(np.float32)
    colors = np.stack([u * 40, v * 50, 255 - u * 30], axis=-1).astype(np.uint8)
    return intr, points, colors


def _write_pcd(path: Path, points: np.ndarray, colors: np.ndarray, data: str, color_type: str) -> None:
    h, w = points.shape[:2]
    c = colors.astype(np.uint32)
    packed = (255 << 24) | (c[..., 0] << 16) | (c[..., 1] << 8) | c[..., 2]
    header = (
        f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F {color_type}\nCOUNT 1 1 1 1\n"
        f"WIDTH {w}\nHEIGHT {h}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {w * h}\nDATA {data}\n"
    )
    rec = np.zeros(w * h, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
    rec["x"], rec["y"], rec["z"] = points.reshape(-1, 3).T
    rec["rgb"] = packed.reshape(-1) if color_type == "U" else (packed.reshape(-1) & 0xFFFFFF)
    if data == "binary":
        body = rec.tobytes()
    else:
        rgb = rec["rgb"] if color_type == "U" else [repr(float(f)) for f in rec["rgb"].view(np.float32)]
        body = "".join(f"{r['x']} {r['y']} {r['z']} {c}\n" for r, c in zip(rec, rgb)).encode()
    path.write_bytes(header.encode() + body)


def _write_ply(path: Path, points: np.ndarray, colors: np.ndarray, fmt: str) -> None:
    h, w = points.shape[:2]
    header = (
        f"ply\nformat {fmt} 1.0\ncomment written by a test\nobj_info num_cols {w}\nobj_info num_rows {h}\n"
        f"element vertex {w * h}\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    rec = np.zeros(w * h, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
    rec["x"], rec["y"], rec["z"] = points.reshape(-1, 3).T
    rec["r"], rec["g"], rec["b"] = colors.reshape(-1, 3).T
    body = (
        rec.tobytes()
        if fmt == "binary_little_endian"
        else "".join(f"{r['x']} {r['y']} {r['z']} {r['r']} {r['g']} {r['b']}\n" for r in rec).encode()
    )
    path.write_bytes(header.encode() + body)


@pytest.mark.parametrize(
    "kind", ["pcd ascii U", "pcd ascii F", "pcd binary U", "pcd binary F", "ply ascii", "ply binary_little_endian"]
)
def test_organized_files_round_trip(tmp_path: Path, kind: str) -> None:
    intr, points, colors = _grid_cloud()
    suffix, fmt, *color_type = kind.split()
    path = tmp_path / f"grid.{suffix}"
    if suffix == "pcd":
        _write_pcd(path, points, colors, fmt, color_type[0])
    else:
        _write_ply(path, points, colors, fmt)
    cap = load_capture(path)
    assert cap.organized and cap.points_cam.shape == (5, 6, 3)
    np.testing.assert_array_equal(np.isnan(cap.points_cam), np.isnan(points))
    np.testing.assert_allclose(cap.points_cam, points, rtol=1e-6, equal_nan=True)
    np.testing.assert_array_equal(cap.colors, colors)
    got = cap.intrinsics
    np.testing.assert_allclose((got.fx, got.fy, got.cx, got.cy), (intr.fx, intr.fy, intr.cx, intr.cy), atol=1e-3)


def test_unorganized_ply(tmp_path: Path) -> None:
    _, points, colors = _grid_cloud()
    path = tmp_path / "flat.ply"
    _write_ply(path, points.reshape(1, -1, 3), colors.reshape(1, -1, 3), "binary_little_endian")
    cap = load_cloud(path)
    assert not cap.organized and cap.points_cam.shape == (30, 3) and cap.intrinsics is None


def test_fit_intrinsics_rejects_non_camera_frames() -> None:
    intr, points, _ = _grid_cloud()
    assert fit_intrinsics(points) is not None
    shuffled = points.reshape(-1, 3)[np.random.default_rng(0).permutation(30)].reshape(5, 6, 3)
    assert fit_intrinsics(shuffled) is None  # points do not sit on their pixels


# ---------------------------------------------------------------------------------------------
# Broken files: always a CaptureError that names the file.


def _good_pcd(tmp_path: Path, data: str) -> bytes:
    _, points, colors = _grid_cloud()
    _write_pcd(tmp_path / "good.pcd", points, colors, data, "U")
    return (tmp_path / "good.pcd").read_bytes()


def _good_ply(tmp_path: Path, fmt: str) -> bytes:
    _, points, colors = _grid_cloud()
    _write_ply(tmp_path / "good.ply", points, colors, fmt)
    return (tmp_path / "good.ply").read_bytes()


BROKEN = {
    "empty.pcd": lambda tmp, real: b"",
    "garbage.pcd": lambda tmp, real: np.random.default_rng(0).bytes(5000),
    "garbage.ply": lambda tmp, real: np.random.default_rng(1).bytes(5000),
    "compressed_truncated.pcd": lambda tmp, real: real[: len(real) // 2],
    "compressed_header_only.pcd": lambda tmp, real: real[: real.index(b"DATA") + 23],
    "binary_truncated.pcd": lambda tmp, real: _good_pcd(tmp, "binary")[:-40],
    "ascii_truncated.pcd": lambda tmp, real: _good_pcd(tmp, "ascii")[:-200],
    "bad_width.pcd": lambda tmp, real: real.replace(b"WIDTH 640", b"WIDTH abc", 1),
    "points_mismatch.pcd": lambda tmp, real: real.replace(b"POINTS 307200", b"POINTS 307201", 1),
    "no_xyz.pcd": lambda tmp, real: real.replace(b"FIELDS x y z rgba", b"FIELDS a b c rgba", 1),
    "bad_data.pcd": lambda tmp, real: real.replace(b"DATA binary_compressed", b"DATA zipped", 1),
    "all_nan.pcd": lambda tmp, real: (
        _good_pcd(tmp, "binary").split(b"DATA binary\n")[0]
        + b"DATA binary\n"
        + np.full(30 * 4, np.nan, "<f4").tobytes()
    ),
    "ply_binary_truncated.ply": lambda tmp, real: _good_ply(tmp, "binary_little_endian")[:-20],
    "ply_ascii_truncated.ply": lambda tmp, real: _good_ply(tmp, "ascii")[:-100],
    "ply_no_vertex.ply": lambda tmp, real: b"ply\nformat ascii 1.0\nelement face 0\nend_header\n",
    "depth.png": lambda tmp, real: b"\x89PNG\r\n\x1a\n" + b"broken" * 20,
    "depth.npy": lambda tmp, real: b"\x93NUMPY garbage",
    "cloud.txt": lambda tmp, real: b"1 2 3\n",
}


@pytest.mark.parametrize("name", sorted(BROKEN))
def test_broken_files_raise_capture_error(tmp_path: Path, real_data: Path, name: str) -> None:
    real = (real_data / "milk_cartoon_all_small_clorox.pcd").read_bytes()
    path = tmp_path / name
    path.write_bytes(BROKEN[name](tmp_path, real))
    with pytest.raises(CaptureError, match=name.replace(".", r"\.")) as err:
        load_capture(path)
    assert isinstance(err.value, ValueError)


def test_missing_file_and_directory(tmp_path: Path) -> None:
    with pytest.raises(CaptureError, match="nothing.pcd: file not found"):
        load_capture(tmp_path / "nothing.pcd")
    (tmp_path / "dir.ply").mkdir()
    with pytest.raises(CaptureError, match="dir.ply: not a file"):
        load_capture(tmp_path / "dir.ply")


# ---------------------------------------------------------------------------------------------
# Depth images


def _synthetic_depth(intr: Intrinsics) -> np.ndarray:
    """Metres: a floor plane with a raised box, and a hole of missing pixels."""
    v, u = np.mgrid[0 : intr.height, 0 : intr.width]
    depth = 0.8 + 1.2 * v / intr.height
    depth[intr.height // 3 : intr.height // 2, intr.width // 3 : intr.width // 2] -= 0.15
    depth[:10, :20] = 0.0
    return depth.astype(np.float32)


def test_depth_png_round_trip(tmp_path: Path) -> None:
    k = Intrinsics.kinect()
    millimetres = np.round(_synthetic_depth(k) * 1000).astype(np.uint16)
    Image.fromarray(millimetres).save(tmp_path / "d.png")
    cap = load_capture(tmp_path / "d.png")
    assert cap.intrinsics == k and cap.organized and cap.source == str(tmp_path / "d.png")
    expected = backproject(millimetres.astype(np.float32) / np.float32(1000), k)
    np.testing.assert_allclose(cap.points_cam, expected, rtol=1e-6, equal_nan=True)
    assert int(cap.valid_mask().sum()) == int((millimetres > 0).sum())


def test_depth_npy_round_trip_and_scale(tmp_path: Path) -> None:
    k = Intrinsics.kinect()
    depth = _synthetic_depth(k)
    depth[5, 300] = np.nan
    np.save(tmp_path / "d.npy", depth)
    cap = load_depth(tmp_path / "d.npy")
    np.testing.assert_allclose(cap.points_cam, backproject(np.nan_to_num(depth), k), rtol=1e-6, equal_nan=True)
    np.save(tmp_path / "mm.npy", depth * 1000)
    np.testing.assert_allclose(
        load_depth(tmp_path / "mm.npy", depth_scale=1000).points_cam, cap.points_cam, rtol=1e-5, equal_nan=True
    )


def test_depth_of_another_size_scales_kinect_intrinsics(tmp_path: Path, caplog) -> None:
    small = Intrinsics(320, 240, 262.5, 262.5, 159.5, 119.5)
    np.save(tmp_path / "small.npy", _synthetic_depth(small))
    with caplog.at_level(logging.INFO, logger="shapeviewer.perception.capture"):
        cap = load_capture(tmp_path / "small.npy")
    assert cap.intrinsics == small
    assert "scaled" in caplog.text and "small.npy" in caplog.text
    np.testing.assert_allclose(cap.points_cam, backproject(_synthetic_depth(small), small), equal_nan=True)


@pytest.mark.parametrize("problem", ["8-bit png", "all zero", "3-D npy", "wrong intrinsics", "bad scale"])
def test_bad_depth_images(tmp_path: Path, problem: str) -> None:
    k = Intrinsics.kinect()
    kwargs = {}
    if problem == "8-bit png":
        path, match = tmp_path / "rgb.png", "RGB image"
        Image.fromarray(np.zeros((480, 640, 3), np.uint8)).save(path)
    elif problem == "all zero":
        path, match = tmp_path / "zero.png", "no valid depth"
        Image.fromarray(np.zeros((480, 640), np.uint16)).save(path)
    elif problem == "3-D npy":
        path, match = tmp_path / "cube.npy", r"2-D \(H, W\)"
        np.save(path, np.ones((4, 4, 4)))
    elif problem == "wrong intrinsics":
        path, match = tmp_path / "d.npy", "given intrinsics"
        np.save(path, _synthetic_depth(k)[:240, :320])
        kwargs["intrinsics"] = k
    else:
        path, match = tmp_path / "d.npy", "depth_scale"
        np.save(path, _synthetic_depth(k))
        kwargs["depth_scale"] = 0
    with pytest.raises(CaptureError, match=match) as err:
        load_depth(path, **kwargs)
    assert path.name in str(err.value)
