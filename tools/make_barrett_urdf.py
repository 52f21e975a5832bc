"""Write static_assets/hands/barrett_bh8_280.urdf: a Barrett BH8-280 built from its published geometry.

Run from the repo root: ``python tools/make_barrett_urdf.py``. The generated URDF is committed.

Geometry (metres, radians), following the kinematics of GraspIt's BH8-280 model:
- Palm frame: origin at the centre of the palm face, +z the approach direction out of the palm.
  The palm is a cylinder of radius 45 mm and height 75 mm below the face.
- Fingers 1 and 2 turn about spread axes parallel to z at x = +25 mm and x = -25 mm; a 50 mm
  knuckle carries each proximal joint. At spread 0 both knuckles point to +y, so fingers 1 and 2
  stand side by side at y = +50 mm facing finger 3, whose proximal joint is fixed at y = -50 mm.
  Spread (0..pi) turns finger 1 about -z and finger 2 about +z, so at pi/2 they face each other
  along x and at pi they stand beside finger 3.
- Each finger: proximal link 70 mm, distal link 55 mm. In a finger's own frame x points to the palm
  axis, z along the open finger (parallel to the approach) and the joints turn about +y, so a
  positive angle closes the finger. Proximal 0..140 deg; the distal joint (relative to the
  proximal link) is coupled as q/3 + 42 deg in shapeviewer.grasp.hands, so its limits are
  42 deg .. 140/3 + 42 deg. GraspIt's extra fixed 5 deg proximal offset is left out: an open
  finger here is exactly parallel to the approach.
Collision geometry is boxes and one cylinder so that contact queries stay fast and stable.
"""

from __future__ import annotations

import math
from pathlib import Path

PALM_RADIUS = 0.045
PALM_HEIGHT = 0.075
SPREAD_AXIS_X = 0.025
KNUCKLE = 0.050
PROXIMAL = 0.070
DISTAL = 0.055
FINGER_WIDTH = 0.025
PROXIMAL_THICKNESS = 0.020
DISTAL_THICKNESS = 0.018
KNUCKLE_HEIGHT = 0.020

FINGER_MAX = math.radians(140.0)
DISTAL_OFFSET = math.radians(42.0)
SPREAD_MAX = math.pi

# Masses (kg) sum to about the real hand's 1.2 kg; only the dynamic lift test uses them.
MASS = {"palm": 0.80, "knuckle": 0.05, "proximal": 0.08, "distal": 0.05}

OUT = Path(__file__).resolve().parents[1] / "static_assets" / "hands" / "barrett_bh8_280.urdf"


def _f(x: float) -> str:
    return f"{x:.9g}"


def _box_inertia(mass: float, size: tuple[float, float, float]) -> str:
    x, y, z = size
    ixx = mass * (y * y + z * z) / 12.0
    iyy = mass * (x * x + z * z) / 12.0
    izz = mass * (x * x + y * y) / 12.0
    return f'<inertia ixx="{_f(ixx)}" ixy="0" ixz="0" iyy="{_f(iyy)}" iyz="0" izz="{_f(izz)}"/>'


def _box_link(
    name: str, mass: float, size: tuple[float, float, float], centre: tuple[float, float, float], colour: str
) -> str:
    xyz = " ".join(_f(c) for c in centre)
    dims = " ".join(_f(s) for s in size)
    geom = f'<origin xyz="{xyz}" rpy="0 0 0"/><geometry><box size="{dims}"/></geometry>'
    return f"""  <link name="{name}">
    <inertial><origin xyz="{xyz}" rpy="0 0 0"/><mass value="{_f(mass)}"/>{_box_inertia(mass, size)}</inertial>
    <visual>{geom}<material name="{colour}"/></visual>
    <collision>{geom}</collision>
  </link>
"""


def _joint(
    name: str,
    parent: str,
    child: str,
    xyz: tuple[float, float, float],
    yaw: float,
    axis: tuple[float, float, float],
    lower: float,
    upper: float,
    effort: float,
) -> str:
    return f"""  <joint name="{name}" type="revolute">
    <parent link="{parent}"/><child link="{child}"/>
    <origin xyz="{" ".join(_f(c) for c in xyz)}" rpy="0 0 {_f(yaw)}"/>
    <axis xyz="{" ".join(_f(a) for a in axis)}"/>
    <limit lower="{_f(lower)}" upper="{_f(upper)}" effort="{_f(effort)}" velocity="1.0"/>
  </joint>
"""


def _finger(prefix: str, parent: str, xyz: tuple[float, float, float], yaw: float) -> str:
    """Proximal and distal links of one finger; ``yaw`` turns the parent frame into the finger frame."""
    prox_size = (PROXIMAL_THICKNESS, FINGER_WIDTH, PROXIMAL)
    dist_size = (DISTAL_THICKNESS, FINGER_WIDTH, DISTAL)
    # Fingertip force of the real hand is about 15 N at ~0.125 m: 2 N m proximal, 1 N m distal.
    return (
        _joint(f"{prefix}_proximal", parent, f"{prefix}_proximal", xyz, yaw, (0, 1, 0), 0.0, FINGER_MAX, 2.0)
        + _box_link(f"{prefix}_proximal", MASS["proximal"], prox_size, (0, 0, PROXIMAL / 2), "link")
        + _joint(
            f"{prefix}_distal",
            f"{prefix}_proximal",
            f"{prefix}_distal",
            (0, 0, PROXIMAL),
            0.0,
            (0, 1, 0),
            DISTAL_OFFSET,
            FINGER_MAX / 3 + DISTAL_OFFSET,
            1.0,
        )
        + _box_link(f"{prefix}_distal", MASS["distal"], dist_size, (0, 0, DISTAL / 2), "tip")
    )


def urdf() -> str:
    """The URDF text."""
    palm_mass = MASS["palm"]
    r, h = PALM_RADIUS, PALM_HEIGHT
    ixx = palm_mass * (3 * r * r + h * h) / 12.0
    izz = palm_mass * r * r / 2.0
    palm_geom = (
        f'<origin xyz="0 0 {_f(-h / 2)}" rpy="0 0 0"/>'
        f'<geometry><cylinder radius="{_f(r)}" length="{_f(h)}"/></geometry>'
    )
    # The base link's inertial frame is the palm frame itself (the cylinder's inertia is kept about
    # its own centre, 37.5 mm behind): pybullet reports, resets and constrains a base by its
    # inertial frame, and keeping the two equal avoids a silent offset for every caller.
    parts = [
        '<?xml version="1.0"?>\n',
        "<!-- Generated by tools/make_barrett_urdf.py; edit that script, not this file. -->\n",
        '<robot name="barrett_bh8_280">\n',
        '  <material name="palm"><color rgba="0.25 0.25 0.28 1"/></material>\n',
        '  <material name="link"><color rgba="0.55 0.57 0.60 1"/></material>\n',
        '  <material name="tip"><color rgba="0.20 0.20 0.20 1"/></material>\n',
        f"""  <link name="palm">
    <inertial><origin xyz="0 0 0" rpy="0 0 0"/><mass value="{_f(palm_mass)}"/>
      <inertia ixx="{_f(ixx)}" ixy="0" ixz="0" iyy="{_f(ixx)}" iyz="0" izz="{_f(izz)}"/></inertial>
    <visual>{palm_geom}<material name="palm"/></visual>
    <collision>{palm_geom}</collision>
  </link>
""",
    ]
    # The knuckle spans the spread hub to the proximal joint, flush with the palm face.
    knuckle_size = (FINGER_WIDTH, KNUCKLE + FINGER_WIDTH, KNUCKLE_HEIGHT)
    knuckle_centre = (0.0, KNUCKLE / 2, -KNUCKLE_HEIGHT / 2)
    for prefix, x, axis_z in (("f1", SPREAD_AXIS_X, -1.0), ("f2", -SPREAD_AXIS_X, 1.0)):
        parts.append(
            _joint(
                f"{prefix}_spread", "palm", f"{prefix}_knuckle", (x, 0, 0), 0.0, (0, 0, axis_z), 0.0, SPREAD_MAX, 1.0
            )
        )
        parts.append(_box_link(f"{prefix}_knuckle", MASS["knuckle"], knuckle_size, knuckle_centre, "palm"))
        # Knuckle frame: +y points from the spread axis to the proximal joint; the finger frame's x
        # must point back to the spread axis (-y), hence a -90 deg yaw.
        parts.append(_finger(prefix, f"{prefix}_knuckle", (0, KNUCKLE, 0), -math.pi / 2))
    # Finger 3 sits on the palm at y = -50 mm; its x (towards the palm axis) is the palm's +y.
    parts.append(_finger("f3", "palm", (0, -KNUCKLE, 0), math.pi / 2))
    parts.append("</robot>\n")
    return "".join(parts)


def main() -> None:
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(urdf())
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
