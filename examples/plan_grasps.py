"""Plan Barrett hand grasps on a completed object, as the paper's robot did.

Completes the largest object of a real capture (fast mesh), moves it into the table-aligned world
frame (table top z = 0, z up), plans ten grasps on it and writes the best three: those that lift the completed
object in the planner's pybullet check first, then by GraspIt's epsilon quality.

    python examples/plan_grasps.py [OUTPUT_FOLDER]
"""

import csv
import sys
import tempfile
from pathlib import Path

import shapeviewer as sv

CAPTURE = Path(__file__).resolve().parents[1] / "static_assets" / "captures" / "milk_cartoon_all_small_clorox.pcd"

if __name__ == "__main__":
    out = Path(sys.argv[1] if len(sys.argv) > 1 else tempfile.mkdtemp(prefix="shapeviewer_"))
    out.mkdir(parents=True, exist_ok=True)

    seg = sv.segment_scene(sv.load_capture(CAPTURE))
    largest = max(seg.segments, key=lambda s: len(s.points_cam))
    mesh = sv.complete(largest.points_cam, support_plane=seg.plane_cam, mode="fast")
    mesh.apply_transform(seg.T_world_cam)  # camera frame -> world frame, standing on z = 0
    mesh.export(out / "object_world.ply")

    # Without budget_seconds planning is deterministic for a seed; the budget only caps a slow machine.
    # Ten grasps, best three kept: the planner lift-checks only what it returns, and few hold an 11 cm carton.
    result = sv.plan_grasps(mesh, hand="barrett", n_grasps=10, seed=0, budget_seconds=40)
    stats = result.stats
    best = result.grasps[:3]
    print(f"{len(result.grasps)} grasps from {stats.evaluations} candidates in {stats.seconds['total']:.1f} s, best 3:")
    with open(out / "grasps.csv", "w", newline="") as f:
        rows = csv.writer(f)
        rows.writerow(["rank", "lifted", "epsilon", "volume", "force_closure", "x", "y", "z"])
        for rank, g in enumerate(best, 1):
            lifted = g.lift is not None and g.lift.success
            print(
                f"#{rank}: {'lifts' if lifted else 'does not lift'} the object, epsilon {g.epsilon:.4f}, "
                f"volume {g.volume:.4f}, palm at {g.position.round(3)} m"
            )
            rows.writerow([rank, lifted, g.epsilon, g.volume, g.force_closure, *g.position])
    print(f"wrote {out / 'object_world.ply'} and {out / 'grasps.csv'}")
