"""What an adversarial user can send the viewer and the commands, each answered within seconds with a
clear message while the server stays up: a FIFO named like a capture, uploads over the cap (announced,
or outgrowing what was announced while they stream), a bad ``--host`` or ``--port``, invalid numeric
options, forged GUI values, names with newlines and markup, a results folder resumed under other
settings, and ``kill -9`` of a run whose workers must not outlive it."""

from __future__ import annotations

import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec
import pytest
import viser
import websockets.sync.client
import zstandard
from viser import _messages as vm

from shapeviewer.cli.commands import main
from shapeviewer.perception.capture import CaptureError, load_capture
from shapeviewer.runtime.interrupt import alive, descendants
from shapeviewer.viewer import ViewerApp

from helpers import free_port, wait_until

CAPTURES = Path(__file__).resolve().parents[2] / "static_assets" / "captures"
MILK = CAPTURES / "milk_cartoon_all_small_clorox.pcd"
MUG = CAPTURES / "table_scene_mug_stereo_textured.pcd"
PART = 512 * 1024  # the viser client's upload part size
HANG = 20.0  # what "answers within seconds" allows, on two busy cores
# A command's own start: importing the viewer (torch, viser, pybullet) takes seconds on a cold, busy machine.
COMMAND_START = 60.0


def in_time(fn: Callable[[], Any], seconds: float = HANG) -> Any:
    """``fn()``, or a failure (not a hung test) when it has not returned within ``seconds``."""
    out: list = []

    def run() -> None:
        try:
            out.append(("ok", fn()))
        except BaseException as e:  # handed to the test's thread
            out.append(("error", e))

    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(seconds)
    if not out:
        pytest.fail(f"no answer within {seconds:.0f} s: it hangs")
    kind, value = out[0]
    if kind == "error":
        raise value
    return value


def shapeviewer(*args: str, timeout: float = 240.0, env: dict | None = None) -> tuple[int, str, str, float]:
    """Run ``python -m shapeviewer ARGS``: ``(exit code, stdout, stderr, seconds)``; fails (does not
    hang) after ``timeout`` seconds."""
    t0 = time.monotonic()
    try:
        done = subprocess.run(
            [sys.executable, "-m", "shapeviewer", *args],
            capture_output=True,
            text=True,
            timeout=timeout,
            stdin=subprocess.DEVNULL,
            env=env,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"shapeviewer {' '.join(args)} did not end within {timeout:.0f} s")
    return done.returncode, done.stdout, done.stderr, time.monotonic() - t0


def one_error_line(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), stderr
    return lines[0]


# ----------------------------------------------------------------------------------------------
# A FIFO named like a capture


@pytest.fixture
def fifo_folder(tmp_path: Path) -> Path:
    for name in ("x.npy", "x.pcd", "x.ply", "x.png"):
        os.mkfifo(tmp_path / name)  # nothing ever writes: opening one for reading blocks forever
    return tmp_path


def test_a_fifo_is_refused_before_anything_opens_it(fifo_folder: Path) -> None:
    for name in ("x.npy", "x.pcd", "x.ply", "x.png"):
        with pytest.raises(CaptureError, match=f"{name}: not a regular file"):
            in_time(lambda name=name: load_capture(fifo_folder / name))
    with pytest.raises(CaptureError, match="^x.npy: not a regular file"):  # named as the browser knows it
        in_time(lambda: load_capture(fifo_folder / "x.npy", name="x.npy"))


def test_commands_refuse_a_fifo_in_one_line(fifo_folder: Path) -> None:
    code, _, err, seconds = shapeviewer("complete", str(fifo_folder / "x.npy"), "--out", str(fifo_folder / "out"))
    assert code == 2 and seconds < COMMAND_START and "not a regular file" in one_error_line(err)
    assert not (fifo_folder / "out").exists()  # the folder it made is gone again
    code, _, err, seconds = shapeviewer("serve", "--cloud", str(fifo_folder / "x.npy"), "--port", str(free_port()))
    assert code == 2 and seconds < COMMAND_START and "not a regular file" in one_error_line(err)


# ----------------------------------------------------------------------------------------------
# A browser tab, as viser's client speaks to the server


class Tab:
    """A websocket to the viewer speaking viser's protocol: messages out as the browser sends them,
    and every message the server sends, decoded."""

    def __init__(self, port: int) -> None:
        self.ws = websockets.sync.client.connect(
            f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"], max_size=None, open_timeout=30
        )
        self.received: list[dict] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        # The browser reports its camera first: viser counts a client as connected from then on.
        self.send(
            vm.ViewerCameraMessage(
                wxyz=(1.0, 0.0, 0.0, 0.0),
                position=(0.0, 0.0, 1.0),
                fov=1.0,
                near=0.01,
                far=100.0,
                image_height=480,
                image_width=640,
                look_at=(0.0, 0.0, 0.0),
                up_direction=(0.0, 0.0, 1.0),
            )
        )

    def _read(self) -> None:
        unzip = zstandard.ZstdDecompressor()
        try:
            for frame in self.ws:
                assert isinstance(frame, bytes)
                size, packed = int.from_bytes(frame[:8], "little"), int.from_bytes(frame[8:16], "little")
                batch = msgspec.msgpack.decode(unzip.decompress(frame[16 : 16 + packed], max_output_size=size))
                self.received.extend(batch["messages"])
        except Exception:  # closed
            pass

    def send(self, message: vm.Message) -> None:
        self.ws.send(msgspec.msgpack.encode(message.as_serializable_dict()))

    def notified(self, *words: str) -> dict | None:
        """The first notification shown whose title and body hold every one of ``words``."""
        for m in list(self.received):
            if m.get("type") in ("NotificationShowMessage", "NotificationUpdateMessage"):
                text = f"{m['props']['title']} {m['props']['body']}"
                if all(w in text for w in words):
                    return m
        return None

    def acked(self, transfer_uuid: str) -> list[dict]:
        return [
            m
            for m in list(self.received)
            if m.get("type") == "FileTransferPartAck" and m["transfer_uuid"] == transfer_uuid
        ]

    def upload(self, component: str, transfer: str, name: str, content: bytes, announce: int | None = None) -> None:
        """Send ``content`` as the browser's upload button does (``announce``: the size it claims)."""
        parts = [content[i : i + PART] for i in range(0, len(content), PART)]
        self.send(
            vm.FileTransferStartUpload(
                source_component_uuid=component,
                transfer_uuid=transfer,
                filename=name,
                mime_type="",
                part_count=len(parts) if announce is None else max(len(parts), -(-announce // PART)),
                size_bytes=len(content) if announce is None else announce,
            )
        )
        for i, part in enumerate(parts):
            self.send(
                vm.FileTransferPart(source_component_uuid=component, transfer_uuid=transfer, part_index=i, content=part)
            )

    def close(self) -> None:
        self.ws.close()


CAP = 2 * 2**20  # the test server's upload cap: the mug capture (1.7 MB) fits, 800 MB does not


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory) -> Path:
    data = tmp_path_factory.mktemp("data")
    shutil.copy(MILK, data / "milk.pcd")
    (data / "broken.pcd").write_bytes(b"# .PCD v0.7\nFIELDS x y z\nnot a cloud\n")
    (data / ".hidden.pcd").symlink_to(data / "milk.pcd")
    (data / "sub").mkdir()
    shutil.copy(MUG, data / "sub" / "mug.pcd")
    os.mkfifo(data / "pipe.npy")
    (data / "evil\nname **bold** <img src=x onerror=alert(1)>.pcd").write_bytes(b"ply\nformat ascii 1.0\nnonsense\n")
    return data


@pytest.fixture(scope="module")
def served(data_dir: Path):
    """A viewer as ``serve`` runs it (a session per browser tab), and one tab connected to it."""
    app = ViewerApp(port=free_port(), cloud=MILK, results=None, data_dir=data_dir, max_upload_bytes=CAP)
    tab = Tab(app.port)
    try:
        session = wait_until(lambda: next(iter(app.sessions.values()), None), 120, "the tab's session")
        wait_until(lambda: session.scene is not None, 60, "the tab's scene")
        yield app, tab, session
    finally:
        tab.close()
        app.stop()


def transfers(session) -> dict:
    return session.audience.gui._current_file_upload_states


def test_an_upload_announced_over_the_cap_is_refused_before_its_bytes_are_kept(served) -> None:
    app, tab, session = served
    before = session.scene
    component = session.panel.upload._impl.uuid
    # 800 MB announced; the browser goes on sending its parts whatever the server says.
    tab.send(
        vm.FileTransferStartUpload(
            source_component_uuid=component,
            transfer_uuid="big",
            filename="big.pcd",
            mime_type="",
            part_count=1600,
            size_bytes=800 * 2**20,
        )
    )
    for i in range(8):
        tab.send(
            vm.FileTransferPart(source_component_uuid=component, transfer_uuid="big", part_index=i, content=bytes(PART))
        )
    note = wait_until(lambda: tab.notified("big.pcd", "800 MB", "at most 2 MB"), HANG, "the refusal")
    assert note["props"]["color"] == "red"
    # The browser's transfer is ended at once, so that its upload button works again.
    assert any(a["transferred_bytes"] == a["total_bytes"] == 800 * 2**20 for a in tab.acked("big"))
    wait_until(lambda: not transfers(session), HANG, "no part of the upload kept")
    assert session.scene is before and session.panel.upload.value.content == b""


def test_an_upload_outgrowing_its_announced_size_is_cut_while_it_streams(served) -> None:
    app, tab, session = served
    before = session.scene
    component = session.panel.upload._impl.uuid
    tab.upload(component, "liar", "liar.pcd", bytes(4 * PART), announce=PART)  # claims 512 KB, sends 2 MB
    wait_until(lambda: tab.notified("liar.pcd", "refused while receiving"), HANG, "the refusal")
    wait_until(lambda: not transfers(session), HANG, "the transfer dropped")
    assert session.scene is before and session.panel.upload.value.content == b""


def test_an_upload_within_the_cap_still_loads_and_is_let_go(served) -> None:
    app, tab, session = served
    before = session.scene
    tab.upload(session.panel.upload._impl.uuid, "mug", "mug.pcd", MUG.read_bytes())
    wait_until(lambda: session.scene is not before and session.scene.capture.source == "mug.pcd", 120, "the upload")
    assert session.panel.upload.value.content == b""  # the bytes are not kept as the button's value


def choose_server_file(tab: Tab, session, value: str) -> None:
    """What a forged client can send: any value for the Server file dropdown, then a click."""
    dropdown, button = session.panel.cloud_path, session.panel.load_cloud
    tab.send(vm.GuiUpdateMessage(uuid=dropdown._impl.uuid, updates={"value": value}))
    tab.send(vm.GuiUpdateMessage(uuid=button._impl.uuid, updates={"value": True}))


@pytest.mark.parametrize("forged", [".hidden.pcd", "sub/mug.pcd", "pipe.npy", "../data/milk.pcd"])
def test_a_forged_server_file_value_is_refused(served, data_dir: Path, forged: str) -> None:
    """Values the list does not offer are refused (viser takes any value a client's message names;
    the list is the server's own, read again at each load); a FIFO among them answers at once."""
    app, tab, session = served
    before = session.scene
    session.last_error = None
    choose_server_file(tab, session, forged)
    wait_until(lambda: session.last_error, HANG, "the refusal")
    assert session.panel.cloud_path.value == forged  # it did reach the server
    assert "not one of the files the Server file list offers" in session.last_error or "outside" in session.last_error
    assert str(data_dir) not in session.last_error and session.scene is before


def test_server_file_errors_name_the_file_not_the_server_path_and_log_one_line(served, data_dir: Path, caplog) -> None:
    app, tab, session = served
    caplog.set_level(logging.INFO)
    for name in ("broken.pcd", "evil\nname **bold** <img src=x onerror=alert(1)>.pcd"):
        assert name in session.data_files()
        session.last_error = None
        before = session.scene
        choose_server_file(tab, session, name)
        error = wait_until(lambda: session.last_error, HANG, f"the error of {name!r}")
        assert str(data_dir) not in error and "\n" not in error and session.scene is before, error
    messages = [r.getMessage() for r in caplog.records if r.name.startswith("shapeviewer")]
    assert messages and all("\n" not in m for m in messages), messages
    assert not any(str(data_dir) in m for m in messages if "broken.pcd" in m)
    # The server is still up: a listed file loads.
    before = session.scene
    choose_server_file(tab, session, "milk.pcd")
    wait_until(lambda: session.scene is not before, 120, "milk.pcd loaded")
    assert session.scene.capture.source == "milk.pcd"


def test_a_npy_of_python_objects_is_no_advice_to_unpickle(tmp_path: Path) -> None:
    import numpy as np

    for shape in ((2,), (4, 3)):
        path = tmp_path / f"objects{len(shape)}.npy"
        np.save(path, np.full(shape, None, dtype=object), allow_pickle=True)
        with pytest.raises(CaptureError) as e:
            load_capture(path, name=path.name)
        assert "a .npy of Python objects is not a capture" in str(e.value) and "allow_pickle" not in str(e.value)


# ----------------------------------------------------------------------------------------------
# serve: --host and --port


def test_serve_refuses_a_host_that_is_not_this_machine() -> None:
    for host, words in (("nosuchhost.invalid", "cannot resolve"), ("8.8.8.8", "not an address of this machine")):
        code, _, err, seconds = shapeviewer("serve", "--host", host, "--port", str(free_port()), timeout=120)
        line = one_error_line(err)
        assert code == 2 and seconds < COMMAND_START and f"--host {host}" in line and words in line, line


def test_serve_refuses_a_busy_port_with_no_free_one_after_it() -> None:
    with socket.socket() as busy:
        try:
            busy.bind(("127.0.0.1", 65535))
        except OSError:
            pass  # someone else listens there: busy all the same
        else:
            busy.listen()
        code, _, err, seconds = shapeviewer("serve", "--port", "65535", timeout=120)
    line = one_error_line(err)
    assert code == 2 and seconds < COMMAND_START and "--port 65535" in line and "in use" in line, line


@pytest.mark.skipif(os.geteuid() == 0, reason="root may listen on any port")
def test_serve_refuses_a_privileged_port() -> None:
    code, _, err, seconds = shapeviewer("serve", "--port", "1", timeout=120)
    line = one_error_line(err)
    assert code == 2 and seconds < COMMAND_START and "--port 1" in line and "1024" in line, line


def test_serve_on_every_interface_prints_only_urls_with_the_token(tmp_path: Path) -> None:
    port = free_port()
    env = {**os.environ, "SHAPEVIEWER_CACHE": str(tmp_path)}
    server = subprocess.Popen(
        [sys.executable, "-m", "shapeviewer", "serve", "--host", "0.0.0.0", "--port", str(port), "--cloud", str(MILK)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        text=True,
        env=env,
    )
    lines: list[str] = []
    try:
        assert server.stdout is not None
        reader = threading.Thread(target=lambda: lines.extend(server.stdout or ()), daemon=True)
        reader.start()
        wait_until(lambda: any("ready on" in line for line in lines), 240, "the server's banner")
    finally:
        server.send_signal(signal.SIGINT)
        server.wait(30)
    urls = [word for line in lines for word in line.split() if word.startswith("http")]
    assert urls and all("?token=" in url for url in urls), lines


@pytest.mark.parametrize(
    "argv, option",
    [
        (["serve", "--port", "99999"], "--port"),
        (["serve", "--port", "-1"], "--port"),
        (["evaluate", "--out", "o", "--workers", "0"], "--workers"),
        (["evaluate", "--out", "o", "--grasp-budget", "nan"], "--grasp-budget"),
        (["evaluate", "--out", "o", "--widen-below", "2"], "--widen-below"),
    ],
)
def test_invalid_numeric_options_are_refused_by_the_parser(argv: list[str], option: str) -> None:
    code, _, err, seconds = shapeviewer(*argv, timeout=120)
    assert code == 2 and seconds < COMMAND_START and option in err and "Traceback" not in err, err


# ----------------------------------------------------------------------------------------------
# evaluate: kill -9, and a folder resumed under other settings


def test_kill_9_of_evaluate_leaves_no_worker_and_the_folder_refuses_other_settings(tmp_path: Path, capsys) -> None:
    out = tmp_path / "results"
    run = subprocess.Popen(
        [sys.executable, "-m", "shapeviewer", "evaluate", "--out", str(out), "--views-per-set", "2", "--workers", "2"]
        + ["--no-progress", "--grasps", "--n-grasps", "2", "--grasp-methods", "Partial"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        stdin=subprocess.DEVNULL,
    )
    try:
        # Mid-run: both workers started and writing meshes.
        wait_until(
            lambda: len(descendants(run.pid)) >= 2 and any((out / "meshes").glob("*.ply")), 300, "the run's work"
        )
        workers = descendants(run.pid)
        os.kill(run.pid, signal.SIGKILL)
        run.wait(10)
        wait_until(lambda: not any(alive(p) for p in workers), 5, f"the workers {workers} to end with their run")
    finally:
        if run.poll() is None:
            run.kill()
    written = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    time.sleep(3)
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == written  # nothing written after
    # Resumed under another grasp budget: refused, naming the option, before any work.
    argv = ["evaluate", "--out", str(out), "--views-per-set", "2", "--workers", "1", "--no-progress"]
    grasps = ["--grasps", "--n-grasps", "2", "--grasp-methods", "Partial"]
    assert main([*argv, *grasps, "--grasp-budget", "5"]) == 2
    err = capsys.readouterr().err
    assert "--grasp-budget none" in err and "asks for 5" in err and "new --out folder" in err, err
    assert main([*argv, "--grasps", "--n-grasps", "3", "--grasp-methods", "Partial"]) == 2
    assert "--n-grasps 2" in capsys.readouterr().err
    assert main([*argv, "--seed", "1"]) == 2 and "--seed 0" in capsys.readouterr().err
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == written
