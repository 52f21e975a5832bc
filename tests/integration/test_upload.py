"""Loading captures from the browser: uploads (any suffix the readers know, size-capped, parsed from a
private temporary folder) and, only with ``--data-dir``, the server's own files inside that folder."""

from __future__ import annotations

import io
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
import viser
from PIL import Image

from shapeviewer.viewer import ViewerApp
from shapeviewer.viewer import panel as P
from shapeviewer.viewer.session import Session
from shapeviewer.viewer.sources import read_upload

from helpers import browser_page, browser_session, free_port, headless_session, needs_browser, node, wait_until

CAPTURES = Path(__file__).resolve().parents[2] / "static_assets" / "captures"
MILK = CAPTURES / "milk_cartoon_all_small_clorox.pcd"
MUG = CAPTURES / "table_scene_mug_stereo_textured.pcd"


def npy_bytes(array: np.ndarray) -> bytes:
    out = io.BytesIO()
    np.save(out, array)
    return out.getvalue()


def random_pcd(n: int, seed: int = 5) -> bytes:
    """An unorganized binary PCD of random points in a 2 m box: no table, no object."""
    points = np.random.default_rng(seed).uniform([-1, -1, 0.5], [1, 1, 2.5], (n, 3))
    header = (
        f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\n"
        f"HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    )
    return header.encode() + points.astype("<f4").tobytes()


def visible_labels(app: Session) -> set[str]:
    """Labels of every GUI input the app created."""
    return {h.label for h in app.audience.gui._gui_input_handle_from_uuid.values() if hasattr(h, "label")}


@pytest.fixture(scope="module")
def app():
    with headless_session(cloud=MILK, results=None) as app:
        yield app


@pytest.fixture
def temp_folders(monkeypatch) -> list[Path]:
    """Every folder ``tempfile.mkdtemp`` makes during the test."""
    made: list[Path] = []
    real = tempfile.mkdtemp

    def spy(*args, **kwargs):
        made.append(Path(real(*args, **kwargs)))
        return str(made[-1])

    monkeypatch.setattr(tempfile, "mkdtemp", spy)
    return made


def upload_through_the_button(app: Session, name: str, content: bytes) -> None:
    """What viser does when a browser's upload completes: set the button's value, call its callbacks."""
    handle = app.panel.upload
    handle._impl.value = viser.UploadedFile(name, content)
    for cb in handle._impl.update_cb:
        cb(viser.GuiEvent(None, 0, handle))


def test_without_data_dir_browsers_cannot_read_server_paths(app):
    assert app.res.data_dir is None and app.panel.cloud_path is None and app.panel.load_cloud is None
    labels = visible_labels(app)
    assert "Upload capture" in labels
    assert not labels & {"Cloud path", "Server file", "Load server file"}
    assert app.load_data_file(str(MUG)) is False
    assert "--data-dir" in app.last_error


def test_an_uploaded_capture_replaces_the_scene(app, temp_folders):
    before = app.scene
    upload_through_the_button(app, "C:\\Users\\me\\captures\\" + MUG.name, MUG.read_bytes())
    scene = app.scene
    assert scene is not before and scene.segments
    assert scene.capture.source == MUG.name  # the browser's file name, not a path of either machine
    assert MUG.name in app.panel.source.content
    for sid in scene.segments:
        assert node(app, f"/segments/seg_{sid}") is not None
    assert temp_folders and not any(f.exists() for f in temp_folders), "the upload's folder was left behind"


# Each bad upload: file name, bytes, words its notification must contain.
BAD = {
    "empty": ("empty.pcd", b"", "the file is empty"),
    "garbage": ("garbage.pcd", bytes(range(256)) * 40, "corrupt or not a PCD file"),
    "garbage_ply": ("noise.ply", b"\x00\xff" * 1000, "not a PLY file"),
    "truncated": ("cut.pcd", MUG.read_bytes()[:500_000], "truncated"),
    "all_nan_points": ("nan.npy", npy_bytes(np.full((100, 3), np.nan)), "none of its 100 points is finite"),
    "all_nan_depth": ("nan_depth.npy", npy_bytes(np.full((48, 64), np.nan)), "no valid depth pixel"),
    "pickle_npy": ("evil.npy", b"\x93NUMPY" + b"x" * 200, "not a readable .npy"),
    "garbage_png": ("photo.png", b"\x89PNG\r\n\x1a\n garbage", "not a readable PNG"),
    "unsupported": ("notes.txt", b"hello", "unsupported file type '.txt'"),
    "no_suffix": ("capture", b"hello", "unsupported file type '(no suffix)'"),
    "no_segment": ("random.pcd", random_pcd(50_000), "current scene is kept"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_upload_is_one_red_line_and_keeps_the_scene(app, temp_folders, case):
    name, content, words = BAD[case]
    before = app.scene
    app.last_error = None
    assert app.load_upload(name, content) is False
    error = app.last_error
    assert error is not None and error.startswith("Could not load the capture: ")
    assert words in error and name in error, error
    assert "\n" not in error and "Traceback" not in error
    assert tempfile.gettempdir() not in error and "capture." not in error.replace(name, ""), error
    assert app.scene is before
    for sid in before.segments:
        assert node(app, f"/segments/seg_{sid}") is not None
    assert not any(f.exists() for f in temp_folders)
    assert not app.jobs.busy


def test_an_upload_over_the_size_cap_is_refused_unread(app, temp_folders, monkeypatch):
    monkeypatch.setattr(app.res, "max_upload_bytes", 1_000_000)
    before = app.scene
    assert app.load_upload(MUG.name, MUG.read_bytes()) is False
    assert "at most 1 MB" in app.last_error and MUG.name in app.last_error
    assert app.scene is before and not temp_folders  # never written to disk
    assert P.MAX_UPLOAD_MB == 200


def test_a_depth_image_upload_says_which_intrinsics_it_assumed(app):
    # A 64x48 depth PNG in millimetres (a slanted plane): parsed without a scene change.
    depth = (800 + np.arange(48)[:, None] * 5 + np.zeros((1, 64))).astype(np.uint16)
    out = io.BytesIO()
    Image.fromarray(depth).save(out, format="PNG")
    capture, note = read_upload("plane.png", out.getvalue(), app.res.intrinsics)
    assert capture.points_cam.shape == (48, 64, 3) and capture.source == "plane.png"
    assert note and "--fx --fy --cx --cy" in note and "Kinect" in note and "64x48" in note
    _, note = read_upload("points.npy", npy_bytes(np.ones((10, 3))), app.res.intrinsics)
    assert note is None  # points need no intrinsics


def test_with_data_dir_only_its_files_are_offered_and_loaded(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    shutil.copy(MILK, data / "milk.pcd")
    (data / "readme.txt").write_text("not a capture")
    outside = tmp_path / "outside.pcd"
    shutil.copy(MUG, outside)
    (data / "link.pcd").symlink_to(outside)  # a symbolic link out of the folder
    with headless_session(cloud=MILK, results=None, data_dir=data) as app:
        assert app.panel.cloud_path is not None and app.panel.load_cloud is not None
        assert {"Server file", "Load server file", "Upload capture"} <= visible_labels(app)
        assert tuple(app.panel.cloud_path.options) == ("milk.pcd",)  # not the link out of the folder
        assert app.panel.load_cloud in app.panel.job_buttons
        before = app.scene
        for name in ("../outside.pcd", str(outside), "link.pcd", "sub/../../outside.pcd"):
            app.last_error = None
            assert app.load_data_file(name) is False, name
            assert "outside the server's data folder" in app.last_error, name
            assert app.scene is before
        assert app.load_data_file("milk.pcd") is True and app.scene is not before
        shutil.copy(MUG, data / "mug.pcd")
        app.last_error = None
        assert app.load_data_file("mug.pcd") is True, app.last_error  # the list is scanned at each load
        assert tuple(app.panel.cloud_path.options) == ("milk.pcd", "mug.pcd")


def test_serve_has_a_data_dir_option():
    from shapeviewer.cli.parser import build_parser

    args = build_parser().parse_args(["serve", "--data-dir", "captures"])
    assert args.data_dir == "captures"
    assert build_parser().parse_args(["serve"]).data_dir is None


def test_a_missing_data_dir_is_refused(tmp_path):
    with pytest.raises(NotADirectoryError, match="not a folder"):
        ViewerApp(port=free_port(), cloud=MILK, results=None, data_dir=tmp_path / "missing")


@needs_browser
@pytest.mark.browser
def test_upload_through_the_browser():
    """Chromium picks the file in viser's (hidden) file input; the server shows the new scene."""
    viewer = ViewerApp(port=free_port(), cloud=MILK, results=None, max_cloud_points=20_000)
    try:
        with browser_page(viewer) as page:
            app = browser_session(viewer)
            before = app.scene
            file_input = page.locator("input[type=file]")
            file_input.first.wait_for(state="attached", timeout=30_000)
            assert file_input.count() == 1
            file_input.first.set_input_files(str(MUG))
            wait_until(lambda: app.scene is not before, 60, "the uploaded scene")
            assert app.scene.capture.source == MUG.name and app.scene.segments
    finally:
        viewer.stop()
