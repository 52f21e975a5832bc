"""Complete the largest object of a real depth capture into a closed mesh.

Loads a Kinect capture shipped with the repository, removes the support plane (a carpet floor
here) and splits the rest into objects, then completes the largest one with the CNN and the
detailed mesher (Algorithm 1 of the paper), resting on the plane.

    python examples/complete_capture.py [OUTPUT_FOLDER]
"""

import sys
import tempfile
from pathlib import Path

import shapeviewer as sv

CAPTURE = Path(__file__).resolve().parents[1] / "static_assets" / "captures" / "milk_cartoon_all_small_clorox.pcd"

if __name__ == "__main__":
    out = Path(sys.argv[1] if len(sys.argv) > 1 else tempfile.mkdtemp(prefix="shapeviewer_"))
    out.mkdir(parents=True, exist_ok=True)

    capture = sv.load_capture(CAPTURE)
    seg = sv.segment_scene(capture)  # the support plane is removed, one segment per object
    largest = max(seg.segments, key=lambda s: len(s.points_cam))
    print(f"{len(seg.segments)} segments, completing the largest: {largest.label}")

    # Camera frame (x right, y down, z forward), metres; the table stops the completion.
    mesh = sv.complete(largest.points_cam, support_plane=seg.plane_cam, mode="detailed")

    path = out / f"segment_{largest.id}_detailed.ply"
    mesh.export(path)
    size_cm = 100 * mesh.extents
    print(f"wrote {path}")
    print(f"watertight: {mesh.is_watertight}")
    print(f"size: {size_cm[0]:.1f} x {size_cm[1]:.1f} x {size_cm[2]:.1f} cm, volume {1e6 * mesh.volume:.0f} cm^3")
