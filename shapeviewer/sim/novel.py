"""Seeded procedural objects of kinds that no training data holds: a test of completion on new kinds.

The completion CNN learns from the catalogue (YCB, pybullet objects and the household families of
:mod:`.household`); a robot meets objects of other kinds too. These families are never in the
catalogue's list, so ``shapeviewer generate`` cannot train on them: ``novel/<kind>_<index>`` names
resolve to a mesh (:func:`catalogue.load_mesh`) and to the holdout-model split, so tabletop views of
them render like any holdout object's (``python -m benchmarks.studies.novel_kinds``).

Conventions as in :mod:`.household`: ``family(rng) -> trimesh.Trimesh``, metres, z up, the object in
its natural resting pose, lowest point at z = 0, bounding box centred on the x-y origin, one
watertight body.
"""

from __future__ import annotations

from collections.abc import Callable

import manifold3d as mf
import numpy as np
import trimesh

from . import solids as S

VERSION = 1  # bump when any family changes shape (mesh caches key on it)
PER_KIND = 20  # novel/<kind>_000 .. _019


def ring(rng: np.random.Generator) -> trimesh.Trimesh:
    """A flat ring lying on the table (tape roll, donut, coaster ring): outer diameter 6-16 cm, a hole
    through it."""
    r_out = rng.uniform(0.03, 0.08)
    r_in = r_out * rng.uniform(0.35, 0.7)
    h = rng.uniform(0.015, 0.06)
    outline = S.section(np.array([[r_in, 0.0], [r_out, 0.0], [r_out, h], [r_in, h]]))
    return S.finish(S.revolve(S.rounded(outline, min(h, r_out - r_in) * 0.3), 72))


def dumbbell(rng: np.random.Generator) -> trimesh.Trimesh:
    """A hand weight lying on its side: a bar between two round or hexagonal weights; 15-30 cm long."""
    length = rng.uniform(0.15, 0.30)
    r_bar = rng.uniform(0.012, 0.02)
    r_end = rng.uniform(0.03, 0.055)
    w_end = rng.uniform(0.03, 0.06)
    sides = int(rng.choice([6, 48]))
    end = mf.Manifold.cylinder(w_end, r_end, r_end, sides).rotate((0.0, 90.0, 0.0))
    bar = mf.Manifold.cylinder(length, r_bar, r_bar, 32).rotate((0.0, 90.0, 0.0)).translate((-length / 2, 0.0, 0.0))
    m = bar + end.translate((-length / 2, 0.0, 0.0)) + end.translate((length / 2 - w_end, 0.0, 0.0))
    return S.finish(m)


def bracket(rng: np.random.Generator) -> trimesh.Trimesh:
    """An L-shaped block (bookend, corner bracket): a base plate and an upright plate; 8-20 cm."""
    w = rng.uniform(0.06, 0.16)
    base, up = rng.uniform(0.08, 0.18), rng.uniform(0.08, 0.2)
    t = rng.uniform(0.008, 0.025)
    r = min(0.003, t / 3)
    plate = S.rounded_box((base, w, t), r).translate((base / 2, 0.0, t / 2))
    upright = S.rounded_box((t, w, up), r).translate((t / 2, 0.0, up / 2))
    return S.finish(plate + upright)


def teapot(rng: np.random.Generator) -> trimesh.Trimesh:
    """A closed, squat teapot: a round body with a lid knob, a spout on one side and a handle on the
    other; 15-25 cm across (spout to handle)."""
    r = rng.uniform(0.05, 0.08)
    h = r * rng.uniform(1.0, 1.5)
    z = np.linspace(0.0, h, 16)
    bulge = np.sin(np.pi * np.clip(z / h, 0.0, 1.0)) ** 0.6
    prof = np.stack([np.maximum(r * (0.55 + 0.45 * bulge), 1e-3), z], 1)
    prof = np.vstack([[0.0, 0.0], prof, [0.0, h]])
    body = S.revolve(S.rounded(S.section(np.vstack([prof, S.mirror(prof)])), 0.004))
    knob = mf.Manifold.sphere(rng.uniform(0.01, 0.018), 24).translate((0.0, 0.0, h))
    spout = S.tube([[0.7 * r, 0.0, 0.3 * h], [1.2 * r, 0.0, 0.6 * h], [1.45 * r, 0.0, 0.95 * h]], [0.016, 0.011, 0.008])
    handle = S.tube(
        [[-0.75 * r, 0.0, 0.75 * h], [-1.35 * r, 0.0, 0.7 * h], [-1.35 * r, 0.0, 0.35 * h], [-0.8 * r, 0.0, 0.25 * h]],
        rng.uniform(0.006, 0.01),
    )
    return S.finish(body + knob + spout + handle)


def wedge(rng: np.random.Generator) -> trimesh.Trimesh:
    """A door stop or cheese wedge: a triangular prism lying on its long face; 8-18 cm long."""
    length, height, width = rng.uniform(0.08, 0.18), rng.uniform(0.025, 0.08), rng.uniform(0.04, 0.1)
    tri = S.rounded(S.section(np.array([[0.0, 0.0], [length, 0.0], [length, height]])), 0.002)
    m = mf.Manifold.extrude(tri, width).rotate((90.0, 0.0, 0.0))
    return S.finish(m)


def stool(rng: np.random.Generator) -> trimesh.Trimesh:
    """A small three-legged stand (plant stand, toy stool): a round top on three splayed legs; 10-25
    cm tall, open underneath."""
    h = rng.uniform(0.10, 0.25)
    r_top = rng.uniform(0.05, 0.1)
    t = rng.uniform(0.01, 0.02)
    r_leg = rng.uniform(0.006, 0.012)
    top = mf.Manifold.cylinder(t, r_top, r_top, 48).translate((0.0, 0.0, h - t))
    legs = []
    for k in range(3):
        a = 2 * np.pi * k / 3
        foot = 1.15 * (r_top - r_leg) * np.array([np.cos(a), np.sin(a)])
        head = 0.7 * (r_top - r_leg) * np.array([np.cos(a), np.sin(a)])
        legs.append(S.tube([[*foot, r_leg], [*head, h - t / 2]], r_leg, 16))
    return S.finish(top + legs[0] + legs[1] + legs[2])


def star(rng: np.random.Generator) -> trimesh.Trimesh:
    """A star-shaped block lying flat (a toy, a cookie cutter's shape, an ornament): 5-7 points,
    8-16 cm across."""
    n = int(rng.integers(5, 8))
    r_out = rng.uniform(0.04, 0.08)
    r_in = r_out * rng.uniform(0.4, 0.6)
    a = np.pi * np.arange(2 * n) / n
    rad = np.where(np.arange(2 * n) % 2 == 0, r_out, r_in)
    outline = S.rounded(S.section(np.stack([rad * np.cos(a), rad * np.sin(a)], 1)), 0.002)
    return S.finish(mf.Manifold.extrude(outline, rng.uniform(0.015, 0.05)))


def vase(rng: np.random.Generator) -> trimesh.Trimesh:
    """A solid hourglass or vase-like turned piece (candle holder, ornament): a narrow waist between a
    wide foot and a wide top; 10-25 cm tall."""
    h = rng.uniform(0.10, 0.25)
    r_foot, r_top = rng.uniform(0.03, 0.06), rng.uniform(0.025, 0.06)
    r_waist = min(r_foot, r_top) * rng.uniform(0.3, 0.6)
    waist = rng.uniform(0.35, 0.65)
    z = np.linspace(0.0, h, 20)
    t = z / h
    radius = np.interp(t, [0.0, waist, 1.0], [r_foot, r_waist, r_top])
    radius = radius + 0.15 * r_waist * np.sin(np.pi * t)
    prof = np.vstack([[0.0, 0.0], np.stack([radius, z], 1), [0.0, h]])
    return S.finish(S.revolve(S.rounded(S.section(np.vstack([prof, S.mirror(prof)])), 0.003)))


FAMILIES: dict[str, Callable[[np.random.Generator], trimesh.Trimesh]] = {
    "ring": ring,
    "dumbbell": dumbbell,
    "bracket": bracket,
    "teapot": teapot,
    "wedge": wedge,
    "stool": stool,
    "star": star,
    "vase": vase,
}
KINDS: tuple[str, ...] = tuple(FAMILIES)


def make(kind: str, index: int) -> trimesh.Trimesh:
    """Object ``index`` of novel family ``kind`` (one of :data:`KINDS`), deterministic; metres, z up,
    resting on z = 0."""
    if kind not in FAMILIES:
        raise KeyError(f"unknown novel kind {kind!r}; one of {', '.join(KINDS)}")
    return FAMILIES[kind](np.random.default_rng(S.seed(f"novel/{kind}", index)))


def names(per_kind: int = PER_KIND) -> list[str]:
    """The catalogue-style names ``novel/<kind>_<index>`` of the first ``per_kind`` objects of every kind."""
    return [f"novel/{k}_{i:03d}" for k in KINDS for i in range(per_kind)]
