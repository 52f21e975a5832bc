"""Capture (paper Fig. 5, step 1): a depth camera's view of a tabletop as a camera-frame point cloud.

A :class:`Capture` is what every later stage starts from, whether it came from the simulated
Kinect of a generated scene (:mod:`shapeviewer.sim.demo_scene`) or from a real sensor file.

Real files are read with :func:`load_capture` (dispatching on the suffix):

* ``.pcd`` / ``.ply`` point clouds (:func:`load_cloud`): ascii, binary or (PCD) binary_compressed,
  organized or not, NaN rows allowed. Points are taken to be in the camera optical frame, metres
  (a PCD's VIEWPOINT is ignored). Organized clouds get intrinsics fitted to their points.
* ``.png`` (uint16 millimetres) / ``.npy`` (float metres) depth images (:func:`load_depth`).
* ``.npy`` arrays of points: (N, 3) or organized (H, W, 3) camera-frame metres (:func:`load_npy_points`).

What a capture may cost is capped: a file of more than :data:`MAX_FILE_POINTS` points is refused
before it is read, and :func:`load_capture` keeps at most :data:`MAX_CAPTURE_POINTS` of the rest
(:func:`decimate`: a regular stride, rows and columns of an organized cloud), logging a warning.

Every problem with a file raises :class:`CaptureError` naming the file and what is wrong with it;
the header checks and raw pixel reads behind that are in :mod:`shapeviewer.perception.readers`.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import trimesh

from .camera import Intrinsics, backproject
from .readers import (
    CaptureError,
    check_file,
    load_npy,
    npy_header,
    pcd_layout,
    ply_layout,
    read_npy_depth,
    read_png_depth,
)

log = logging.getLogger(__name__)


@dataclass
class SceneObject:
    """A ground-truth object of a synthetic scene.

    Attributes:
        name: catalogue name (see :mod:`shapeviewer.sim.catalogue`).
        mesh: watertight mesh in the object frame, metres.
        T_world_obj: 4x4 pose of the object in the world frame.
    """

    name: str
    mesh: trimesh.Trimesh
    T_world_obj: np.ndarray


@dataclass
class Capture:
    """One depth capture.

    Attributes:
        points_cam: camera optical frame metres (x right, y down, z forward); (H, W, 3) when the
            cloud is organized, else (N, 3). NaN rows mark invalid pixels.
        colors: uint8 RGB with the same leading shape as ``points_cam``, or None.
        intrinsics: the camera's intrinsics when known (organized clouds, depth images).
        T_world_cam: 4x4 pose of the camera in the world frame. Synthetic scenes know it; for real
            captures it is identity until segmentation estimates a table-aligned world frame.
        source: where the capture came from (a path, or ``default(seed=N)``).
        objects: ground truth of synthetic scenes (empty for real captures).
        labels: per-pixel ground-truth object index (same leading shape, -1 = none) for synthetic scenes.
        original_points: points (rows, NaN included) of the file before :func:`decimate` kept fewer;
            None when nothing was dropped.
    """

    points_cam: np.ndarray
    colors: np.ndarray | None = None
    intrinsics: Intrinsics | None = None
    T_world_cam: np.ndarray = field(default_factory=lambda: np.eye(4))
    source: str = ""
    objects: list[SceneObject] = field(default_factory=list)
    labels: np.ndarray | None = None
    original_points: int | None = None

    @property
    def organized(self) -> bool:
        return self.points_cam.ndim == 3

    def flat_points(self) -> np.ndarray:
        """(N, 3) camera-frame metres, NaN rows kept (index i matches ``flat_colors()[i]``)."""
        return self.points_cam.reshape(-1, 3)

    def flat_colors(self) -> np.ndarray | None:
        return None if self.colors is None else self.colors.reshape(-1, 3)

    def valid_mask(self) -> np.ndarray:
        """(N,) bool: rows of ``flat_points()`` that are finite."""
        return np.isfinite(self.flat_points()).all(axis=1)

    def decimation_note(self) -> str | None:
        """What :func:`decimate` dropped, in words for the user; None when the capture is whole."""
        if self.original_points is None:
            return None
        return f"{self.original_points:,} points: kept {len(self.flat_points()):,} for segmentation and completion"


CLOUD_SUFFIXES = (".pcd", ".ply")
DEPTH_SUFFIXES = (".png", ".npy")
# What one capture may cost. Segmentation and completion keep at most this many points (a
# 1280x720 frame fits whole; 5 M points cost 3.4 GB and 20 s to segment, 1 M about 0.4 GB and 3 s).
MAX_CAPTURE_POINTS = 1_000_000
# Files declaring more points (or depth pixels) than this are refused unread: Open3D and PIL
# would hold all of them (10 M points are about 0.5 GB as Open3D reads them).
MAX_FILE_POINTS = 10_000_000
# A pinhole model fitted to an organized cloud must reproduce its pixel grid this well (RMS pixels),
# otherwise the cloud is not in its camera's optical frame and the fit means nothing.
_MAX_FIT_RMS_PX = 0.5


def load_capture(
    path: str | os.PathLike,
    intrinsics: Intrinsics | None = None,
    max_points: int | None = MAX_CAPTURE_POINTS,
    *,
    name: str | None = None,
) -> Capture:
    """Read a point cloud (``.pcd``, ``.ply``, ``.npy`` of points) or a depth image (``.png``, ``.npy``).

    A ``.npy`` holding an (N, 3) or (H, W, 3) array is points (camera frame, metres); a 2-D
    (H, W) one is a depth image.

    Args:
        path: the file.
        intrinsics: the camera's intrinsics. Depth images need them (default: the Kinect's, see
            :func:`load_depth`); organized clouds get them fitted when omitted.
        max_points: keep at most this many points (:func:`decimate`, with a logged warning);
            None keeps all.
        name: what messages and the capture's ``source`` call the file (default: ``path``), e.g.
            its name in the server's data folder, so that a browser never sees the server's paths.

    Raises:
        CaptureError: the file is missing, not a regular file (a FIFO or device is refused before
            anything opens it), of an unsupported type, unreadable, or larger than :data:`MAX_FILE_POINTS`.
    """
    path = Path(path)
    if name is None:
        return _load_capture(path, intrinsics, max_points)
    try:
        capture = _load_capture(path, intrinsics, max_points)
    except CaptureError as e:
        raise CaptureError(str(e).replace(str(path), name)) from None
    capture.source = name
    return capture


def _load_capture(path: Path, intrinsics: Intrinsics | None, max_points: int | None) -> Capture:
    check_file(path)  # before any open: a FIFO named x.npy must not block the reader
    suffix = path.suffix.lower()
    if suffix in CLOUD_SUFFIXES:
        capture = load_cloud(path, intrinsics)
    elif suffix == ".npy" and npy_holds_points(path):
        capture = load_npy_points(path, intrinsics)
    elif suffix in DEPTH_SUFFIXES:
        capture = load_depth(path, intrinsics)
    else:
        raise CaptureError(
            f"{path}: unsupported file type {suffix or '(no suffix)'!r}; "
            f"expected a point cloud ({', '.join(CLOUD_SUFFIXES)}) or a depth image "
            f"({', '.join(DEPTH_SUFFIXES)})"
        )
    if max_points is not None:
        capture = decimate(capture, max_points)
        if capture.original_points is not None:
            log.warning("%s: %s", path, capture.decimation_note())
    return capture


def decimate(capture: Capture, max_points: int) -> Capture:
    """``capture`` with at most ``max_points`` points (rows of ``flat_points()``, NaN rows included).

    A regular stride, cheap for any size and deterministic: every k-th row and column of an
    organized cloud (which stays organized, its intrinsics scaled to the kept pixels), every k-th
    point of an unorganized one. Colours and labels follow; ``original_points`` records the count
    before. A capture within the limit is returned as it is.
    """
    if max_points < 1:
        raise ValueError(f"max_points must be at least 1, got {max_points}")
    n = len(capture.flat_points())
    if n <= max_points:
        return capture
    if capture.organized:
        h, w = capture.points_cam.shape[:2]
        k = max(2, int(np.ceil(np.sqrt(n / max_points))))
        while -(-h // k) * -(-w // k) > max_points:
            k += 1
        keep: tuple = (slice(None, None, k), slice(None, None, k))
        intr = capture.intrinsics
        if intr is not None:  # pixel (u', v') of the kept grid is pixel (k u', k v') of the original
            intr = Intrinsics(-(-w // k), -(-h // k), intr.fx / k, intr.fy / k, intr.cx / k, intr.cy / k)
    else:
        keep = (slice(None, None, int(np.ceil(n / max_points))),)
        intr = capture.intrinsics

    def take(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else np.ascontiguousarray(a[keep])

    return replace(
        capture,
        points_cam=np.ascontiguousarray(capture.points_cam[keep]),
        colors=take(capture.colors),
        labels=take(capture.labels),
        intrinsics=intr,
        original_points=n if capture.original_points is None else capture.original_points,
    )


def load_npy_points(path: str | os.PathLike, intrinsics: Intrinsics | None = None) -> Capture:
    """Read a ``.npy`` of points: (N, 3) unorganized or (H, W, 3) organized, camera optical frame metres.

    NaN rows mark invalid points. Organized arrays get intrinsics fitted when none are given.

    Raises:
        CaptureError: unreadable, not such an array, larger than :data:`MAX_FILE_POINTS`, or no finite point.
    """
    path = check_file(path)
    raw = load_npy(path)
    if raw.ndim not in (2, 3) or raw.shape[-1] != 3 or raw.size == 0:
        raise CaptureError(f"{path}: expected (N, 3) or (H, W, 3) points in metres, got {raw.shape}")
    if not (np.issubdtype(raw.dtype, np.integer) or np.issubdtype(raw.dtype, np.floating)):
        raise CaptureError(f"{path}: expected numeric points, got dtype {raw.dtype}")
    n = raw.size // 3
    if n > MAX_FILE_POINTS:
        raise CaptureError(f"{path}: {n:,} points; at most {MAX_FILE_POINTS:,} can be loaded")
    points = np.asarray(raw, dtype=np.float64)
    if not np.isfinite(points).all(axis=-1).any():
        raise CaptureError(f"{path}: none of its {n} points is finite (all NaN/inf)")
    if points.ndim == 3:
        intrinsics = _organized_intrinsics(points, intrinsics, path)
    return Capture(points_cam=points, intrinsics=intrinsics, source=str(path))


def _organized_intrinsics(points: np.ndarray, intrinsics: Intrinsics | None, path: Path) -> Intrinsics | None:
    """The intrinsics of an organized (H, W, 3) cloud: fitted to its points when not given (None if
    they fit no pinhole), else checked against its size (CaptureError when they do not match)."""
    h, w = points.shape[:2]
    if intrinsics is None:
        return fit_intrinsics(points, source=str(path))
    if (intrinsics.width, intrinsics.height) != (w, h):
        raise CaptureError(
            f"{path}: the cloud is organized {w}x{h} but the given intrinsics "
            f"are for {intrinsics.width}x{intrinsics.height}"
        )
    return intrinsics


def npy_holds_points(path: Path) -> bool:
    """Whether a ``.npy`` file's header says (N, 3) or (H, W, 3), i.e. points rather than a depth image.

    Reads the header only, from a regular file only (see :func:`~.readers.check_file`)."""
    try:
        shape, _ = npy_header(Path(path))
    except CaptureError:  # not a .npy, a broken one, or not a regular file: load_depth says what is wrong
        return False
    return len(shape) in (2, 3) and shape[-1] == 3


def load_cloud(path: str | os.PathLike, intrinsics: Intrinsics | None = None) -> Capture:
    """Read a ``.pcd`` or ``.ply`` point cloud, keeping NaN rows and the organization.

    A PCD is organized when its HEIGHT is over 1; a PLY when it carries PCL's
    ``obj_info num_cols`` / ``num_rows`` lines. Organized clouds come back as (H, W, 3).

    Args:
        path: the file. Points are taken as camera optical frame metres (x right, y down, z forward).
        intrinsics: the camera's intrinsics. Organized clouds must match their size; when omitted
            they are fitted to the points (:func:`fit_intrinsics`). Unorganized clouds keep what is
            given (None by default).

    Raises:
        CaptureError: missing/empty file, corrupt header, truncated data, no finite point, or
            intrinsics of the wrong size.
    """
    import open3d as o3d

    path = check_file(path)
    suffix = path.suffix.lower()
    if suffix == ".pcd":
        n_points, width, height = pcd_layout(path)
    elif suffix == ".ply":
        n_points, width, height = ply_layout(path)
    else:
        raise CaptureError(f"{path}: not a point cloud file (expected {' or '.join(CLOUD_SUFFIXES)})")
    if n_points > MAX_FILE_POINTS:
        raise CaptureError(f"{path}: {n_points:,} points; at most {MAX_FILE_POINTS:,} can be loaded")
    # Our own header checks above catch what Open3D would only warn about (or fill with zeros).
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        cloud = o3d.io.read_point_cloud(path, format=suffix[1:], remove_nan_points=False, remove_infinite_points=False)
    points = np.asarray(cloud.points, dtype=np.float64)
    if len(points) != n_points:
        raise CaptureError(
            f"{path}: the header declares {n_points} points but {len(points)} could be read; the file is corrupt"
        )
    if not np.isfinite(points).all(axis=1).any():
        raise CaptureError(f"{path}: none of its {n_points} points is finite (all NaN/inf)")
    # Open3D decodes PCL's packed rgb/rgba (float or uint, ascii/binary/compressed) correctly.
    colors = np.round(np.asarray(cloud.colors) * 255.0).astype(np.uint8) if cloud.has_colors() else None

    if height > 1:
        points = points.reshape(height, width, 3)
        colors = None if colors is None else colors.reshape(height, width, 3)
        intrinsics = _organized_intrinsics(points, intrinsics, path)
    return Capture(points_cam=points, colors=colors, intrinsics=intrinsics, source=str(path))


def load_depth(
    path: str | os.PathLike, intrinsics: Intrinsics | None = None, depth_scale: float | None = None
) -> Capture:
    """Read a depth image and back-project it into an organized (H, W, 3) camera-frame cloud.

    Args:
        path: ``.png`` (single-channel 16-bit, millimetres by default) or ``.npy`` (2-D float array,
            metres by default). Zero, negative and non-finite depths are missing pixels (NaN points).
        intrinsics: must match the image size. Default: the Kinect's (:meth:`Intrinsics.kinect`),
            scaled to the image size when it is not 640x480 (logged).
        depth_scale: stored units per metre (Open3D's convention). Default 1000 for PNG, 1 for NPY.

    Raises:
        CaptureError: missing/empty/unreadable file, not a single-channel depth image, no valid
            pixel, a non-positive ``depth_scale`` or intrinsics of the wrong size.
    """
    path = check_file(path)
    suffix = path.suffix.lower()
    if suffix == ".png":
        raw, default_scale = read_png_depth(path, MAX_FILE_POINTS), 1000.0
    elif suffix == ".npy":
        raw, default_scale = read_npy_depth(path, MAX_FILE_POINTS), 1.0
    else:
        raise CaptureError(f"{path}: not a depth image file (expected {' or '.join(DEPTH_SUFFIXES)})")
    scale = default_scale if depth_scale is None else float(depth_scale)
    if not (np.isfinite(scale) and scale > 0):
        raise CaptureError(f"{path}: depth_scale must be a positive number of units per metre, got {depth_scale!r}")
    with np.errstate(invalid="ignore"):
        depth = raw.astype(np.float32) / np.float32(scale)
        valid = np.isfinite(depth) & (depth > 0)
    if not valid.any():
        raise CaptureError(f"{path}: no valid depth pixel (all {depth.size} are zero, negative or NaN)")
    depth[~valid] = 0.0
    intr = _depth_intrinsics(path, depth.shape, intrinsics)
    return Capture(points_cam=backproject(depth, intr).astype(np.float64), intrinsics=intr, source=str(path))


def fit_intrinsics(points_cam: np.ndarray, source: str = "cloud") -> Intrinsics | None:
    """Pinhole intrinsics of an organized cloud, by least squares over its valid pixels.

    Fits ``u = fx * x / z + cx`` and ``v = fy * y / z + cy`` where (u, v) is each point's pixel
    (column, row). Returns None (and logs why) when there are too few valid pixels or when the
    fit leaves over half a pixel RMS, i.e. the points are not in their camera's optical frame.

    Args:
        points_cam: (H, W, 3) camera-frame metres, NaN for invalid pixels.
        source: what to call the cloud in log messages.
    """
    h, w = points_cam.shape[:2]
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(points_cam).all(axis=2) & (points_cam[..., 2] > 0)
    v, u = np.nonzero(ok)
    if len(u) < 10:
        log.warning("%s: only %d valid pixels, intrinsics unknown", source, len(u))
        return None
    p = points_cam[v, u]
    a, b = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
    if np.ptp(a) <= 0 or np.ptp(b) <= 0:
        log.warning("%s: valid pixels span a single row or column, intrinsics unknown", source)
        return None
    fx, cx = np.polyfit(a, u, 1)
    fy, cy = np.polyfit(b, v, 1)
    rms = float(np.sqrt(np.mean((fx * a + cx - u) ** 2 + (fy * b + cy - v) ** 2)))
    if rms > _MAX_FIT_RMS_PX:
        log.warning(
            "%s: the points do not project onto their pixels (pinhole fit RMS %.2f px), intrinsics unknown", source, rms
        )
        return None
    log.info("%s: fitted intrinsics fx=%.2f fy=%.2f cx=%.2f cy=%.2f (RMS %.3f px)", source, fx, fy, cx, cy, rms)
    return Intrinsics(w, h, float(fx), float(fy), float(cx), float(cy))


def _depth_intrinsics(path: Path, shape: tuple[int, int], intrinsics: Intrinsics | None) -> Intrinsics:
    h, w = shape
    if intrinsics is not None:
        if (intrinsics.width, intrinsics.height) != (w, h):
            raise CaptureError(
                f"{path}: the depth image is {w}x{h} but the given intrinsics are for "
                f"{intrinsics.width}x{intrinsics.height}"
            )
        return intrinsics
    k = Intrinsics.kinect()
    if (k.width, k.height) == (w, h):
        return k
    sx, sy = w / k.width, h / k.height
    # Pixel centres sit at integer coordinates, so the principal point scales about -0.5.
    scaled = Intrinsics(w, h, k.fx * sx, k.fy * sy, (k.cx + 0.5) * sx - 0.5, (k.cy + 0.5) * sy - 0.5)
    log.info(
        "%s: %dx%d depth image and no intrinsics given: using the Kinect's scaled to that size "
        "(fx=%.1f fy=%.1f cx=%.1f cy=%.1f)",
        path,
        w,
        h,
        scaled.fx,
        scaled.fy,
        scaled.cx,
        scaled.cy,
    )
    return scaled
