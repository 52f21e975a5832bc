"""Rounds of clutter removal (VGN / GIGA's ``clutter_removal.run``), their resumable records and the summary.

A round: a new world with up to OBJECTS_PER_ROUND objects (:func:`.scene.generate_scene`); then,
until the table is clear, MAX_CONSECUTIVE_FAILURES attempts in a row failed, or the method finds no
grasp: one side-view capture with "dex" noise, its segmentation, the method's ranked grasps, and
the first one executed (:func:`.execute.execute_grasp`).

Round ``r`` of seed ``s`` draws its scene from ``default_rng([s, r])`` and its noise from
``default_rng([s, r, 1])``, so every method meets the same scenes and a round can be run again
alone. Output folder::

    OUT/summary.json
    OUT/<method>/seed_<s>/round_<rrr>.json          a finished round (the resume marker)
    OUT/<method>/seed_<s>/round_<rrr>/attempt_<kk>.npz   each attempt's depth image, intrinsics, T_world_cam

Metrics, pooled over a seed's rounds: GSR = successes / attempts, DR = successes / objects (in
percent); the summary gives their mean and standard deviation over the seeds. ``no_grasp`` ends a
round without an attempt, so attempts = successes + the other failures.
"""

from __future__ import annotations

import contextlib
import json
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np

from ..errors import ShapeviewerError
from ..fileio import atomic_write
from ..perception.segment import SegmentationError, segment_scene
from .execute import FAILURE_KINDS, execute_grasp
from .methods import METHODS, Method, WorldInfo, get_method
from .scene import OBJECTS_PER_ROUND, SCENES, ClutterError, ClutterWorld, ObjectSet, SceneKind, Setup, generate_scene
from .sensor import capture_view

MAX_CONSECUTIVE_FAILURES = 2
ATTEMPT_SECONDS = 120.0  # a method's time per attempt; it is stopped ATTEMPT_GRACE later if it does not stop
ATTEMPT_GRACE = 5.0


class AttemptTimeout(ShapeviewerError, TimeoutError):
    """A method did not return within its time (plus ATTEMPT_GRACE)."""


@contextlib.contextmanager
def _hard_limit(seconds: float) -> Iterator[None]:
    """Raise :class:`AttemptTimeout` in the block after ``seconds`` (a SIGALRM timer; in the main
    thread only, elsewhere the method's own ``cancel`` check is the limit)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def fire(signum, frame):
        raise AttemptTimeout(f"the method did not return within {seconds:.0f} s")

    previous = signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0.0)
        signal.signal(signal.SIGALRM, previous)


def _plan(method: Method, capture, info_args: dict, seconds: float) -> tuple[list, int, float, bool]:
    """(grasps, segments, seconds taken, timed out) of one attempt's segmentation and method."""
    t0 = time.perf_counter()
    deadline = t0 + seconds
    info = WorldInfo(**info_args, cancel=lambda: time.perf_counter() > deadline)
    try:
        with _hard_limit(seconds + ATTEMPT_GRACE):
            try:
                segmentation = segment_scene(capture)
            except SegmentationError:
                return [], 0, time.perf_counter() - t0, False
            grasps = method(capture, segmentation, info)
    except AttemptTimeout:
        return [], 0, time.perf_counter() - t0, True
    taken = time.perf_counter() - t0
    if taken > seconds:  # a method that overran its time is not credited with its grasp
        return [], len(segmentation.segments), taken, True
    return list(grasps), len(segmentation.segments), taken, False


def run_round(
    scene: SceneKind,
    objects: ObjectSet,
    method_name: str,
    *,
    seed: int,
    round_index: int,
    setup: Setup | None = None,
    folder: Path | None = None,
    count: int = OBJECTS_PER_ROUND,
    attempt_seconds: float = ATTEMPT_SECONDS,
    noise: bool = True,
) -> dict:
    """One round of ``method_name`` on a ``scene`` drawn from ``objects``; its record (plain data).

    ``folder``: where each attempt's depth image is written (``attempt_<kk>.npz``); None writes nothing.
    """
    method = get_method(method_name)
    t0 = time.perf_counter()
    noise_rng = np.random.default_rng([seed, round_index, 1]) if noise else None
    attempts: list[dict] = []
    with ClutterWorld(setup) as world:
        generate_scene(world, scene, objects, count, np.random.default_rng([seed, round_index]))
        n_objects = world.num_objects
        placed = world.object_poses()
        failures_in_row = 0
        end = "cleared"
        while world.num_objects > 0:
            if failures_in_row >= MAX_CONSECUTIVE_FAILURES:
                end = "failures"
                break
            k = len(attempts)
            capture, depth = capture_view(
                world, noise_rng, source=f"clutter {scene} seed {seed} round {round_index} attempt {k}"
            )
            if folder is not None:
                folder.mkdir(parents=True, exist_ok=True)
                np.savez_compressed(
                    folder / f"attempt_{k:02d}.npz",
                    depth=depth,
                    K=capture.intrinsics.K if capture.intrinsics else np.eye(3),
                    T_world_cam=capture.T_world_cam,
                )
            info_args = {"T_world_cam": capture.T_world_cam, "seed": seed * 100_000 + round_index * 100 + k}
            grasps, n_segments, taken, timed_out = _plan(method, capture, info_args, attempt_seconds)
            record: dict = {
                "attempt": k,
                "depth": f"{folder.name}/attempt_{k:02d}.npz" if folder is not None else None,
                "segments": n_segments,
                "pick_s": taken,
                "timed_out": timed_out,
            }
            if not grasps:
                attempts.append({**record, "grasp": None, "outcome": "no_grasp"})
                end = "no_grasp"
                break
            outcome = execute_grasp(world, grasps[0])
            attempts.append(
                {
                    **record,
                    "grasp": grasps[0].to_dict(),
                    "candidates": len(grasps),
                    "outcome": outcome.kind,
                    "object": outcome.object,
                    "width": outcome.width,
                    "approach_contact": outcome.approach_contact,
                }
            )
            failures_in_row = 0 if outcome.success else failures_in_row + 1
        left = world.num_objects
    executed = [a for a in attempts if a["outcome"] != "no_grasp"]
    return {
        "scene": scene,
        "method": method_name,
        "seed": seed,
        "round": round_index,
        "objects": n_objects,
        "placed": placed,
        "attempts": len(executed),
        "successes": sum(a["outcome"] == "success" for a in executed),
        "left": left,
        "end": end,
        "log": attempts,
        "seconds": time.perf_counter() - t0,
    }


def summarize(records: Sequence[dict], seeds: Sequence[int]) -> dict:
    """One method's figures from its round records (see the module docstring)."""
    gsr, dr = [], []
    for s in seeds:
        mine = [r for r in records if r["seed"] == s]
        att, suc, obj = (sum(r[k] for r in mine) for k in ("attempts", "successes", "objects"))
        gsr.append(100.0 * suc / att if att else 0.0)
        dr.append(100.0 * suc / obj if obj else 0.0)
    failures = dict.fromkeys(FAILURE_KINDS, 0)
    times = []
    for r in records:
        for a in r["log"]:
            times.append(a["pick_s"])
            if a["outcome"] != "success":
                failures[a["outcome"]] += 1
    return {
        "rounds": len(records),
        "attempts": sum(r["attempts"] for r in records),
        "successes": sum(r["successes"] for r in records),
        "objects": sum(r["objects"] for r in records),
        "gsr": float(np.mean(gsr)) if gsr else 0.0,
        "dr": float(np.mean(dr)) if dr else 0.0,
        "gsr_std": float(np.std(gsr)) if gsr else 0.0,
        "dr_std": float(np.std(dr)) if dr else 0.0,
        "pick_s_median": float(np.median(times)) if times else 0.0,
        "failures": failures,
    }


def clear_table(
    out: str | Path,
    *,
    scene: SceneKind,
    objects: str | Path,
    setup: str | Path | None = None,
    rounds: int = 10,
    seeds: Sequence[int] = (0,),
    methods: Sequence[str] = ("Highest",),
    count: int = OBJECTS_PER_ROUND,
    attempt_seconds: float = ATTEMPT_SECONDS,
    noise: bool = True,
    report: Callable[[str], None] | None = None,
) -> dict:
    """Run the clutter-removal benchmark: ``rounds`` rounds per seed and method, written to ``out``
    (resumable: rounds with a record are read, not run again); returns the summary, also written to
    ``out/summary.json``. ``report`` gets a line per round.

    Raises:
        ClutterError: a bad object-set or setup folder, scene or count.
        ValueError: an unknown method.
    """
    if scene not in SCENES:
        raise ClutterError(f"unknown scene {scene!r}; choose one of {', '.join(SCENES)}")
    if rounds < 1 or count < 1:
        raise ClutterError("rounds and objects per round must be at least 1")
    for m in methods:
        get_method(m)
    object_set = ObjectSet.load(objects)
    world_setup = Setup.load(setup)
    root = Path(out)
    root.mkdir(parents=True, exist_ok=True)
    by_method: dict[str, list[dict]] = {m: [] for m in methods}
    for method in methods:
        for seed in seeds:
            folder = root / method / f"seed_{seed}"
            for r in range(rounds):
                done = folder / f"round_{r:03d}.json"
                if done.is_file():
                    record = json.loads(done.read_text())
                    status = "done before"
                else:
                    folder.mkdir(parents=True, exist_ok=True)
                    record = run_round(
                        scene,
                        object_set,
                        method,
                        seed=seed,
                        round_index=r,
                        setup=world_setup,
                        folder=folder / f"round_{r:03d}",
                        count=count,
                        attempt_seconds=attempt_seconds,
                        noise=noise,
                    )
                    atomic_write(done, json.dumps(record, indent=1))
                    status = f"{record['seconds']:.1f} s"
                by_method[method].append(record)
                if report is not None:
                    report(
                        f"{method} seed {seed} round {r + 1}/{rounds}: {record['successes']}/{record['objects']} "
                        f"objects in {record['attempts']} attempts, ended: {record['end']} ({status})"
                    )
    summary = {
        "scene": scene,
        "objects": str(object_set.folder),
        "hand": "panda",
        "rounds": rounds,
        "seeds": list(seeds),
        "objects_per_round": count,
        "methods": {m: summarize(by_method[m], seeds) for m in methods},
    }
    atomic_write(root / "summary.json", json.dumps(summary, indent=1))
    return summary


__all__ = ["METHODS", "clear_table", "run_round", "summarize"]
