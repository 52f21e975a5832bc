"""Seeded random assemblies of primitives: training shapes of no particular kind.

The catalogue's objects come in kinds (cans, mugs, drills...); a robot meets objects of other kinds.
These are unions of 2-4 primitives (rounded boxes, cylinders standing or lying, ellipsoids, frustums,
bent rods), each touching the ones before it, sometimes with an open cavity cut into the top (a
thin-walled hollow) or a hole through the body. They teach the completion network shapes in general
(parts joined at angles, overhangs, hollows) rather than one more kind. Two kinds: ``parts`` (the
first part hollow in ``HOLLOW_SHARE`` of them) and ``hollow`` (always, with smaller parts attached
outside it: vessels of no particular kind, whose unseen walls the network finds hardest). They are
never in the catalogue's list: training data names them (``shapeviewer generate --objects $(python
-c ...)``, see the model card), and the evaluation, which draws objects kind by kind from the
catalogue, is unchanged.
:mod:`.novel`'s kinds stay out of training and measure what they generalise to.

Conventions as in :mod:`.household`: metres, z up, lowest point at z = 0, bounding box centred on the
x-y origin, one watertight body. ``assembly/<kind>_<index>`` names resolve through the catalogue.
"""

from __future__ import annotations

import manifold3d as mf
import numpy as np
import trimesh

from . import solids as S

VERSION = 2  # bump when the family changes shape (mesh caches key on it)
PER_KIND = 1000  # assembly/parts_000 .. _999
KINDS: tuple[str, ...] = ("parts", "hollow")
SIZE = (0.06, 0.26)  # m: the assembly's largest side, drawn uniformly
HOLLOW_SHARE = 0.3  # assemblies whose first part is hollow, open at one end
HOLE_SHARE = 0.15  # assemblies with a hole through them


def _primitive(rng: np.random.Generator, hollow: bool = False) -> mf.Manifold:
    """One part, about 2-10 cm, centred near the origin in a random orientation. ``hollow``: a convex
    part (box, cylinder, ellipsoid or frustum) with an open cavity cut into one end, its walls
    6-15 % of its smallest side."""
    a, b, c = rng.uniform(0.02, 0.1, 3)
    kind = rng.integers(4 if hollow else 5)
    if kind == 0:
        m = S.rounded_box((a, b, c), min(a, b, c) * rng.uniform(0.05, 0.3))
    elif kind == 1:
        m = mf.Manifold.cylinder(c, a / 2, a / 2, int(rng.choice([6, 8, 48]))).translate((0.0, 0.0, -c / 2))
    elif kind == 2:
        m = mf.Manifold.sphere(0.5, 32).scale((a, b, c))
    elif kind == 3:
        m = mf.Manifold.cylinder(c, a / 2, a / 2 * rng.uniform(0.2, 1.0), 48).translate((0.0, 0.0, -c / 2))
    else:  # a rod bent once
        r = min(a, b) * rng.uniform(0.1, 0.25)
        bend = rng.uniform(-1.0, 1.0, 3) * c
        m = S.tube([[-c, 0.0, 0.0], bend * 0.5, [c, bend[1], 0.0]], r)
    if hollow:
        # A convex part scaled about its centre stays inside it: the cavity is that copy's top part,
        # swept up out through the top face (the hull of it and a raised copy, as it is convex).
        lo, hi = S.bounds(m)
        size = hi - lo
        wall = float(np.min(size)) * rng.uniform(0.06, 0.15)
        inner = m.scale(tuple(np.maximum(1.0 - 2.0 * wall / size, 0.1)))
        depth = size[2] * rng.uniform(0.5, 0.85)
        keep = mf.Manifold.cube(tuple(size * 2), center=True).translate((0.0, 0.0, hi[2] - depth + size[2]))
        cavity = inner ^ keep
        m = m - (cavity + cavity.translate((0.0, 0.0, size[2]))).hull()
    return m.rotate(tuple(rng.uniform(0.0, 360.0, 3)))


def _attach(body: mf.Manifold, part: mf.Manifold, rng: np.random.Generator, outside: bool = False) -> mf.Manifold:
    """``part`` moved so that it overlaps ``body`` near a random point of ``body``'s surface (of its
    convex hull if ``outside``, so that it does not fill a cavity)."""
    mesh = (body.hull() if outside else body).to_mesh()
    verts = np.asarray(mesh.vert_properties)[:, :3]
    anchor = verts[rng.integers(len(verts))]
    lo, hi = S.bounds(part)
    centre = (lo + hi) / 2
    # Sink the part's centre a quarter of its size into the body, so that the two always overlap.
    inward = S.bounds(body).mean(0) - anchor
    inward /= max(np.linalg.norm(inward), 1e-9)
    shift = anchor + inward * 0.25 * float(np.min(hi - lo)) - centre
    return body + part.translate(tuple(shift))


def parts(rng: np.random.Generator) -> trimesh.Trimesh:
    """A union of 2-4 primitives, the first sometimes hollow, the whole sometimes pierced; 6-26 cm."""
    body = _primitive(rng, hollow=rng.random() < HOLLOW_SHARE)
    for _ in range(int(rng.integers(1, 4))):
        body = _attach(body, _primitive(rng), rng)
    return _finish(body, rng)


def hollow(rng: np.random.Generator) -> trimesh.Trimesh:
    """A thin-walled hollow open at one end, with 0-2 smaller parts (handles, knobs, feet) attached;
    sometimes pierced; 6-26 cm. Vessels of no particular kind: their unseen walls are what the
    network finds hardest."""
    body = _primitive(rng, hollow=True)
    side = float(np.ptp(S.bounds(body), axis=0).min())
    for _ in range(int(rng.integers(0, 3))):
        part = _primitive(rng)
        extent = float(np.ptp(S.bounds(part), axis=0).max())
        part = part.scale((rng.uniform(0.3, 0.8) * side / extent,) * 3)  # smaller than the hollow
        body = _attach(body, part, rng, outside=True)
    return _finish(body, rng)


def _finish(body: mf.Manifold, rng: np.random.Generator) -> trimesh.Trimesh:
    """``body`` centred and scaled to ``SIZE``, maybe pierced, as one watertight mesh on z = 0."""
    lo, hi = S.bounds(body)
    body = body.translate(tuple(-(lo + hi) / 2)).scale((float(rng.uniform(*SIZE)) / float(np.max(hi - lo)),) * 3)
    size = np.ptp(S.bounds(body), axis=0)
    if rng.random() < HOLE_SHARE:  # a hole through the body along a random horizontal axis
        r = float(np.min(size)) * rng.uniform(0.1, 0.25)
        hole = mf.Manifold.cylinder(float(np.max(size)) * 2, r, r, 32, center=True)
        body = body - hole.rotate((90.0, 0.0, float(rng.uniform(0.0, 180.0))))
    return S.finish(_largest(body))


def _largest(m: mf.Manifold) -> mf.Manifold:
    """The largest connected body of ``m`` (a cut can leave a sliver apart)."""
    bodies = m.decompose()
    return max(bodies, key=lambda b: b.volume()) if len(bodies) > 1 else m


_MAKERS = {"parts": parts, "hollow": hollow}


def make(kind: str, index: int) -> trimesh.Trimesh:
    """Assembly ``index`` of ``kind`` (:func:`parts` or :func:`hollow`), deterministic; metres, z up,
    resting on z = 0."""
    if kind not in KINDS:
        raise KeyError(f"unknown assembly kind {kind!r}; one of {', '.join(KINDS)}")
    return _MAKERS[kind](np.random.default_rng(S.seed(f"assembly/{kind}", index)))


def names(count: int = PER_KIND, kind: str = "parts") -> list[str]:
    """The catalogue-style names ``assembly/<kind>_<index>`` of the first ``count`` assemblies of ``kind``."""
    return [f"assembly/{kind}_{i:03d}" for i in range(count)]
