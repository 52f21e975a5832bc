"""manifold3d building blocks of the procedural shapes (:mod:`.household`, :mod:`.novel`,
:mod:`.assembly`): revolved profiles, thin-walled vessels, rounded boxes, swept tubes, handles, smooth
warps, the final check that turns a body into a placed trimesh, and each object's generator seed. All
lengths in metres; profiles are (r, z) in the object frame (z up)."""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from itertools import pairwise

import manifold3d as mf
import numpy as np
import numpy.typing as npt
import trimesh

SEGMENTS = 64  # circle resolution of revolved bodies
MIN_FACES, MAX_FACES = 1000, 30000

Array = np.ndarray


def seed(key: str, index: int) -> list[int]:
    """The generator seed of object ``index`` of a family named ``key`` (stable across machines and
    Python runs)."""
    return [int(hashlib.sha1(key.encode()).hexdigest()[:8], 16), int(index)]


def section(points: Array) -> mf.CrossSection:
    """A 2D region from one closed polygon (either orientation)."""
    p = np.asarray(points, dtype=np.float64)
    area = 0.5 * np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
    return mf.CrossSection([p if area > 0 else p[::-1]])


def mirror(p: Array) -> Array:
    """A profile (r, z) reflected to the -r side and reversed, to close a region symmetric about the axis."""
    return np.asarray(p)[::-1] * [-1.0, 1.0]


def revolve(cs: mf.CrossSection, segments: int = SEGMENTS) -> mf.Manifold:
    """Revolve the x >= 0 part of a region in the (r, z) plane about the z axis."""
    return mf.Manifold.revolve(cs, segments)


def rounded(cs: mf.CrossSection, convex: float, concave: float = 0.0) -> mf.CrossSection:
    """Fillet a region's convex corners with radius ``convex`` and its concave ones with ``concave``."""
    if concave > 0:
        cs = cs.offset(concave, mf.JoinType.Round, 2.0, 24).offset(-concave, mf.JoinType.Round, 2.0, 24)
    if convex > 0:
        cs = cs.offset(-convex, mf.JoinType.Round, 2.0, 24).offset(convex, mf.JoinType.Round, 2.0, 24)
    return cs.simplify(2e-5)  # offsets leave runs of near-duplicate points


def solid_profile(profile: npt.ArrayLike) -> mf.CrossSection:
    """The region under a profile (r, z) that starts on the axis at the bottom and ends on it at the top."""
    p = np.asarray(profile, dtype=np.float64)
    return section(np.vstack([p, mirror(p)]))


def vessel(outer: Array, wall: float, floor: float) -> tuple[mf.CrossSection, mf.CrossSection]:
    """(wall, cavity) regions of an open-topped vessel in the (r, z) plane, symmetric about r = 0.

    ``outer`` is the outer surface from the bottom edge (r0 > 0, z = 0) up to the rim (R, H). The
    cavity is the inside offset by ``wall`` and lies above z = ``floor``; it is open above the rim.
    The wall's outer corners are rounded (0.4 wall) and the inner floor corner filleted.
    """
    outer = np.asarray(outer, dtype=np.float64)
    r_max, top = outer[:, 0].max(), outer[-1, 1]
    ext = np.vstack([outer, [outer[-1, 0], top + 4 * wall]])
    solid = section(np.vstack([outer, mirror(outer)]))
    cavity = section(np.vstack([ext, mirror(ext)])).offset(-wall, mf.JoinType.Round, 2.0, 32)
    cavity = cavity ^ mf.CrossSection.square((4 * r_max, 4 * top)).translate((-2 * r_max, floor))
    return rounded(solid - cavity, 0.4 * wall, min(2 * wall, 0.008)), cavity


def profile_radius(outer: Array) -> Callable[[float], float]:
    """Outer radius of a vessel profile at height z (profile heights increasing)."""
    outer = np.asarray(outer)
    return lambda z: float(np.interp(z, outer[:, 1], outer[:, 0]))


def rounded_box(size: tuple[float, float, float], r: float, segments: int = 24) -> mf.Manifold:
    """A box of ``size`` centred at the origin with edges rounded to radius ``r``."""
    h = np.maximum(np.asarray(size, dtype=np.float64) / 2 - r, 1e-5)
    s = mf.Manifold.sphere(r, segments)
    return mf.Manifold.batch_hull(
        [s.translate((x, y, z)) for x in (-h[0], h[0]) for y in (-h[1], h[1]) for z in (-h[2], h[2])]
    )


def tube(
    points: npt.ArrayLike,
    radii: npt.ArrayLike,
    segments: int = 24,
    squash: tuple[float, float, float] = (1.0, 1.0, 1.0),
) -> mf.Manifold:
    """A swept round bar: the union of hulls of consecutive balls (radius per point, optionally squashed)."""
    pts = np.asarray(points, dtype=np.float64)
    rad = np.broadcast_to(np.asarray(radii, dtype=np.float64), len(pts))
    balls = [mf.Manifold.sphere(float(r), segments).scale(squash).translate(tuple(p)) for p, r in zip(pts, rad)]
    return mf.Manifold.batch_boolean([mf.Manifold.batch_hull([a, b]) for a, b in pairwise(balls)], mf.OpType.Add)


def sweep(
    path: npt.ArrayLike,
    radii: npt.ArrayLike,
    normal: npt.ArrayLike,
    around: int = 24,
    squash: float = 1.0,
    round_ends: tuple[bool, bool] = (True, True),
) -> mf.Manifold:
    """A tube along a planar ``path`` (N, 3) with plane normal ``normal``: elliptical sections of radius
    ``radii`` in the plane and ``squash * radii`` along the normal; ends are half-ellipsoids or flat.

    The path's curvature radius must exceed the tube radius (no check).
    """
    P = np.asarray(path, dtype=np.float64)
    R = np.broadcast_to(np.asarray(radii, dtype=np.float64), len(P)).copy()
    keep = np.r_[True, np.linalg.norm(np.diff(P, axis=0), axis=1) > 1e-9]
    P, R = P[keep], R[keep]
    nrm = np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
    T = np.gradient(P, axis=0)
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    for end, sign in ((0, -1.0), (-1, 1.0)):  # cap rings: a quarter ellipse down to a pole
        if round_ends[end]:
            a = np.linspace(0, np.pi / 2, 7)[1:-1]
            rings = P[end] + sign * T[end] * (R[end] * np.sin(a))[:, None]
            rr, tt = R[end] * np.cos(a), np.repeat(T[end][None], len(a), 0)
            P, R, T = (
                (np.vstack([rings[::-1], P]), np.concatenate([rr[::-1], R]), np.vstack([tt, T]))
                if end == 0
                else (np.vstack([P, rings]), np.concatenate([R, rr]), np.vstack([T, tt]))
            )
    e1 = np.cross(T, nrm)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    th = np.linspace(0, 2 * np.pi, around, endpoint=False)
    ring = np.cos(th)[None, :, None] * e1[:, None] + squash * np.sin(th)[None, :, None] * nrm[None, None]
    V = (P[:, None] + R[:, None, None] * ring).reshape(-1, 3)
    poles = [P[0] - T[0] * (R[0] if round_ends[0] else 0.0), P[-1] + T[-1] * (R[-1] if round_ends[1] else 0.0)]
    n, j = len(P), np.arange(around)
    k = (j + 1) % around
    faces = [np.stack([i * around + j, i * around + k, (i + 1) * around + k], 1) for i in range(n - 1)]
    faces += [np.stack([i * around + j, (i + 1) * around + k, (i + 1) * around + j], 1) for i in range(n - 1)]
    faces += [
        np.stack([np.full(around, n * around), k, j], 1),
        np.stack([np.full(around, n * around + 1), (n - 1) * around + j, (n - 1) * around + k], 1),
    ]
    V, F = np.vstack([V, poles]), np.vstack(faces)
    if np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum() < 0:
        F = F[:, ::-1]
    return mf.Manifold(mf.Mesh(vert_properties=V.astype(np.float32), tri_verts=F.astype(np.uint32)))


def fillet(corners: npt.ArrayLike, radius: npt.ArrayLike, n: int = 8) -> Array:
    """A 2D polyline with each inner corner replaced by a circular arc of ``radius`` (clamped to fit)."""
    c = np.asarray(corners, dtype=np.float64)
    rad = np.broadcast_to(np.asarray(radius, dtype=np.float64), len(c))
    out = [c[0]]
    for i in range(1, len(c) - 1):
        a, b = c[i - 1] - c[i], c[i + 1] - c[i]
        la, lb = np.linalg.norm(a), np.linalg.norm(b)
        a, b = a / la, b / lb
        half = np.arccos(np.clip(a @ b, -1, 1)) / 2
        d = min(rad[i] / np.tan(half), 0.5 * la, 0.5 * lb)
        r = d * np.tan(half)
        centre = c[i] + (a + b) / np.linalg.norm(a + b) * r / np.sin(half)
        p0, p1 = c[i] + a * d - centre, c[i] + b * d - centre
        t0, t1 = np.arctan2(p0[1], p0[0]), np.arctan2(p1[1], p1[0])
        t1 = t0 + (t1 - t0 + np.pi) % (2 * np.pi) - np.pi
        t = np.linspace(t0, t1, n)
        out.extend(centre + r * np.stack([np.cos(t), np.sin(t)], 1))
    out.append(c[-1])
    return np.asarray(out)


def handle(
    radius_at: Callable[[float], float],
    z_lo: float,
    z_hi: float,
    reach: float,
    bar: float,
    wall: float,
    rng: np.random.Generator,
    side: float = 1.0,
) -> mf.Manifold:
    """A D- or C-shaped handle in the x-z plane whose two ends sink into a wall of outer radius ``radius_at(z)``.

    ``reach`` is how far the loop stands off the wall, ``bar`` the bar radius; ``side`` +1 puts it on +x.
    """
    x_hi, x_lo = radius_at(z_hi) - wall / 2, radius_at(z_lo) - wall / 2
    far = max(radius_at(z_hi), radius_at(z_lo)) + reach
    tilt = rng.uniform(-0.25, 0.25) * reach
    corners = np.array([[x_hi, z_hi], [far + tilt, z_hi], [far - tilt, z_lo], [x_lo, z_lo]])
    span = min(reach, (z_hi - z_lo) / 2)
    path = fillet(corners, [0, *(rng.uniform(min(1.6 * bar, span), span, 2)), 0], 10)
    pts = np.stack([side * path[:, 0], np.zeros(len(path)), path[:, 1]], 1)
    return sweep(pts, bar, [0.0, 1.0, 0.0], 24, rng.uniform(1.0, 1.7), (False, False))


def bounds(m: mf.Manifold) -> np.ndarray:
    """``m``'s axis-aligned bounding box as a (2, 3) array: the lowest and the highest corner (metres)."""
    return np.asarray(m.bounding_box()).reshape(2, 3)


def radial_noise(m: mf.Manifold, rng: np.random.Generator, amp: float, waves: int = 4) -> mf.Manifold:
    """Smooth lumps: scale each vertex's distance from the bounding-box centre by 1 + a sum of sinusoids
    of its direction (always a valid deformation: directions are kept, radii stay positive)."""
    lo, hi = bounds(m)
    c = (lo + hi) / 2
    d = rng.normal(size=(waves, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    freq, phase, a = rng.uniform(1.5, 4.0, waves), rng.uniform(0, 2 * np.pi, waves), rng.uniform(0.3, 1, waves) * amp

    def warp(v: Array) -> Array:
        off = np.asarray(v) - c
        u = off / np.maximum(np.linalg.norm(off, axis=1, keepdims=True), 1e-12)
        return c + off * (1 + (a * np.sin(u @ d.T * freq + phase)).sum(1))[:, None]

    return m.warp_batch(warp)


def finish(m: mf.Manifold, size: float | None = None) -> trimesh.Trimesh:
    """Check one closed body, optionally scale its largest side to ``size``, and place it (z min 0, x-y centred)."""
    if m.status() != mf.Error.NoError or m.is_empty():
        raise ValueError(f"manifold error {m.status()}")
    bodies = len(m.decompose())
    if bodies != 1:
        raise ValueError(f"{bodies} bodies")
    lo, hi = bounds(m)
    if size is not None:
        m = m.scale(tuple([size / float((hi - lo).max())] * 3))
    if m.num_tri() < MIN_FACES:
        m = m.refine(int(np.ceil(np.sqrt(MIN_FACES / m.num_tri()))))
    if m.num_tri() > MAX_FACES:
        m = m.simplify(2e-4)
    out = m.to_mesh64()
    v = np.asarray(out.vert_properties, dtype=np.float64)[:, :3]
    lo, hi = v.min(0), v.max(0)
    v = v - [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]
    # manifold's output is already an oriented closed mesh: keep its topology exactly (no vertex merging)
    return trimesh.Trimesh(v, np.asarray(out.tri_verts, dtype=np.int64), process=False)
