"""Seeded procedural household objects (mugs, bowls, bottles, drills...) for training the completion CNN.

Every family is a function ``family(rng) -> trimesh.Trimesh`` that draws its proportions from ``rng``
and builds a closed solid with manifold3d (revolved profiles, rounded boxes, hulled spheres, swept
tubes, smooth warps and booleans). All meshes are in **metres** and in the object frame: z up, the object in its natural
resting pose (cups open side up, a banana or a hammer lying on the table, a drill standing on its
battery), its lowest point at z = 0 and its bounding box centred on the x-y origin. They are
watertight, a single body, with positive volume and 1k-30k faces. Open vessels (mug, cup, bowl,
plate, pitcher) are thin-walled shells with a real cavity; a handle makes the surface genus 1.

:func:`make` builds object ``index`` of a family deterministically: the seed comes from the family
name and the index, so ``make("mug", 3)`` draws the same shape in every run (vertex for vertex with the
same manifold3d version). Family-specific axes: mug handles and pitcher spouts, drill chucks, spray
nozzles and tool heads point along +x.
"""

from __future__ import annotations

from collections.abc import Callable

import manifold3d as mf
import numpy as np
import trimesh
from scipy.interpolate import PchipInterpolator

from . import solids as S

VERSION = 1  # bump when any family changes shape (mesh caches and catalogue indexes key on it)

# Largest bounding-box side (metres) each family is drawn to: the documented size ranges.
SIZE_RANGE: dict[str, tuple[float, float]] = {
    "mug": (0.07, 0.14),
    "cup": (0.07, 0.15),
    "bowl": (0.10, 0.22),
    "plate": (0.15, 0.26),
    "bottle": (0.15, 0.32),
    "can": (0.05, 0.20),
    "box": (0.05, 0.30),
    "spray_bottle": (0.20, 0.30),
    "drill": (0.15, 0.25),
    "banana": (0.15, 0.22),
    "pitcher": (0.15, 0.25),
    "jar": (0.08, 0.16),
    "fruit": (0.06, 0.11),
    "tool": (0.15, 0.30),
}

Array = np.ndarray


# ----------------------------------------------------------------------------------------------
# Families


def mug(rng: np.random.Generator) -> trimesh.Trimesh:
    """Thin-walled cup (wall 3-6 mm, closed floor) with a D handle; height 7-12 cm, diameter 6.5-9.5 cm."""
    h, r = rng.uniform(0.07, 0.12), rng.uniform(0.0325, 0.0475)
    r_bottom = r * (1 - rng.choice([0.0, rng.uniform(0.03, 0.15)]))
    belly = rng.choice([0.0, rng.uniform(-0.004, 0.004)])
    wall = rng.uniform(0.003, 0.006)
    z = np.linspace(0, h, 12)
    outer = np.stack([r_bottom + (r - r_bottom) * z / h + belly * np.sin(np.pi * z / h), z], 1)
    wall_cs, cavity = S.vessel(outer, wall, rng.uniform(wall, 0.012))
    bar = rng.uniform(0.004, 0.0065)
    z_hi = h - bar - rng.uniform(0.006, 0.02)
    z_lo = max(rng.uniform(0.12, 0.35) * h, bar + 0.004, z_hi - 0.075)
    handle = S.handle(S.profile_radius(outer), z_lo, z_hi, rng.uniform(0.018, 0.032), bar, wall, rng)
    return S.finish(S.revolve(wall_cs) + (handle - S.revolve(cavity)))


def cup(rng: np.random.Generator) -> trimesh.Trimesh:
    """Tapered handle-less cup or tumbler (wall 2-4 mm, sometimes a thick base or a rolled rim); 7-15 cm tall."""
    h = rng.uniform(0.07, 0.15)
    r_top = rng.uniform(0.028, min(0.0475, 0.45 * h))
    r_bottom = r_top * rng.uniform(0.62, 0.95)
    wall = rng.uniform(0.002, 0.004)
    floor = wall + rng.choice([0.0, rng.uniform(0.0, 0.015)])
    z = np.linspace(0, h, 10)
    s = z / h
    outer = np.stack([r_bottom + (r_top - r_bottom) * s ** rng.uniform(0.8, 1.3), z], 1)
    wall_cs, _ = S.vessel(outer, wall, floor)
    if rng.random() < 0.4:  # rolled rim
        bead = rng.uniform(0.0015, 0.0025)
        ring = mf.CrossSection.circle(bead, 16)
        wall_cs = wall_cs + ring.translate((r_top, h - bead)) + ring.translate((-r_top, h - bead))
    return S.finish(S.revolve(wall_cs))


def _foot(cs: mf.CrossSection, radius: float, width: float, height: float) -> mf.CrossSection:
    """Lift a vessel region by ``height`` and stand it on a foot ring of outer ``radius``."""
    ring = mf.CrossSection.square((width, height + 0.003)).translate((radius - width, 0.0))
    return cs.translate((0.0, height)) + ring + ring.mirror((1.0, 0.0))


def bowl(rng: np.random.Generator) -> trimesh.Trimesh:
    """Hollow bowl with a curved profile, diameter 10-22 cm, height 4-9 cm, wall 3-6 mm, maybe a foot ring."""
    r = rng.uniform(0.05, 0.11)
    h = rng.uniform(0.04, min(0.09, 1.1 * r))
    r0 = r * rng.uniform(0.25, 0.5)
    wall = rng.uniform(0.003, 0.006)
    foot = rng.random() < 0.5
    hf = rng.uniform(0.003, 0.008) if foot else 0.0
    phi = np.linspace(0, np.pi / 2, 24)
    outer = np.stack(
        [r0 + (r - r0) * np.sin(phi) ** rng.uniform(0.8, 1.2), (h - hf) * (1 - np.cos(phi) ** rng.uniform(0.8, 1.4))], 1
    )
    wall_cs, _ = S.vessel(outer, wall, wall)
    if foot:
        wall_cs = _foot(wall_cs, r0 * rng.uniform(0.8, 1.1), rng.uniform(0.003, 0.006), hf)
    return S.finish(S.revolve(wall_cs, 80))


def plate(rng: np.random.Generator) -> trimesh.Trimesh:
    """Shallow dish: a flat well, a rising cavetto and a sloped rim; diameter 15-26 cm, height 1.5-3 cm,
    4-6 mm thick."""
    r, h, t = rng.uniform(0.075, 0.13), rng.uniform(0.015, 0.03), rng.uniform(0.004, 0.006)
    foot = rng.random() < 0.5
    hf = rng.uniform(0.002, 0.004) if foot else 0.0
    top = h - hf - t
    r0 = r * rng.uniform(0.4, 0.65)
    r1 = r0 + (r - r0) * rng.uniform(0.2, 0.5)
    h1 = top * rng.uniform(0.55, 0.85)
    s = np.linspace(0, 1, 12)
    rise = np.stack([r0 + (r1 - r0) * s, h1 * (3 * s**2 - 2 * s**3)], 1)
    rim = np.stack([np.linspace(r1, r, 8)[1:], np.linspace(h1, top, 8)[1:]], 1)
    outer = np.vstack([rise, rim, [[r, top + t]]])
    wall_cs, _ = S.vessel(outer, t, t)
    if foot:
        wall_cs = _foot(wall_cs, r0 * rng.uniform(0.85, 1.0), rng.uniform(0.003, 0.006), hf)
    return S.finish(S.revolve(wall_cs, 96))


def _bottle_profile(
    rng: np.random.Generator, h: float, r_body: float, r_neck: float, neck: float, cap: float, r_cap: float
) -> tuple[Array, float, float]:
    """Closed bottle profile (r, z) from the bottom centre to the top centre, plus the shoulder's z range."""
    shoulder = (h - neck - cap) * rng.uniform(0.15, 0.35)
    z_sh = h - cap - neck - shoulder
    f = min(0.3 * r_body, rng.uniform(0.004, 0.012))
    a = np.linspace(-np.pi / 2, 0, 6)
    base = np.stack([r_body - f + f * np.cos(a), f + f * np.sin(a)], 1)
    zb = np.linspace(f, z_sh, 8)[1:]
    waist = rng.choice([0.0, rng.uniform(0.0, 0.12)]) * r_body
    body = np.stack([r_body - waist * np.sin(np.pi * (zb - f) / (z_sh - f)) ** 2, zb], 1)
    s = np.linspace(0, 1, 12)[1:]
    sh = np.stack([r_neck + (r_body - r_neck) * np.cos(np.pi / 2 * s) ** rng.uniform(0.5, 1.6), z_sh + shoulder * s], 1)
    fc = min(0.002, 0.3 * cap)
    top = [[r_neck, h - cap], [r_cap, h - cap], [r_cap, h - fc], [r_cap - fc, h], [0.0, h]]
    return np.vstack([[[0.0, 0.0]], base, body, sh, top]), z_sh, z_sh + shoulder


def _reshape(m: mf.Manifold, sy: float, square: float, z0: float, z1: float) -> mf.Manifold:
    """Turn a round body into an oval (y scaled by ``sy``) and/or a rounded square (superellipse exponent
    ``square``; 2 keeps it round) below z0, blending back to the round shape at z1 (necks stay round)."""

    def warp(v: Array) -> Array:
        v = np.array(v, dtype=np.float64)
        s = np.clip((v[:, 2] - z0) / max(z1 - z0, 1e-9), 0, 1)
        w = 1 - (3 * s**2 - 2 * s**3)
        th = np.arctan2(v[:, 1], v[:, 0])
        rho = (np.abs(np.cos(th)) ** square + np.abs(np.sin(th)) ** square) ** (-1 / square)
        k = 1 + (rho - 1) * w
        v[:, 0] *= k
        v[:, 1] *= k * (1 + (sy - 1) * w)
        return v

    return m.warp_batch(warp)


def bottle(rng: np.random.Generator) -> trimesh.Trimesh:
    """Closed bottle: body, shoulder, neck and cap; 15-32 cm tall, round, oval or square-ish body."""
    h = rng.uniform(0.15, 0.32)
    r_cap = rng.uniform(0.012, 0.022)
    r_body = rng.uniform(max(r_cap + 0.01, 0.025), min(0.05, 0.2 * h))
    prof, z0, z1 = _bottle_profile(
        rng, h, r_body, r_cap - rng.uniform(0.001, 0.003), rng.uniform(0.005, 0.04), rng.uniform(0.015, 0.03), r_cap
    )
    m = S.revolve(S.solid_profile(prof), 96)
    variant = rng.choice(["round", "oval", "square"])
    if variant != "round":
        m = _reshape(m, rng.uniform(0.55, 0.9), rng.uniform(3, 6) if variant == "square" else 2.0, z0, z1)
    return S.finish(m)


def can(rng: np.random.Generator) -> trimesh.Trimesh:
    """Food or drink can: a cylinder with necked-in, beaded rims and a recessed lid; 5-20 cm tall, 5-11 cm wide."""
    h, r = rng.uniform(0.05, 0.20), rng.uniform(0.025, 0.055)
    n, e, lid = rng.uniform(0.0015, 0.004), rng.uniform(0.002, 0.004), rng.uniform(0.002, 0.005)
    neck, w = rng.uniform(0.003, 0.01), rng.uniform(0.0015, 0.0025)
    dome = rng.uniform(0.002, 0.006) if h > 0.08 else 0.001
    zs = np.linspace(neck, h - neck, 24)
    ribs = rng.choice([0.0, rng.uniform(0.0005, 0.0012)])
    body = np.stack([r - ribs * np.sin(np.pi * rng.integers(3, 9) * (zs - neck) / (h - 2 * neck)) ** 2, zs], 1)
    prof = np.vstack(
        [
            [[0.0, dome], [r - n - 0.003, 0.0025], [r - n - 0.0005, 0.0], [r - n + 0.0005, 0.0]],
            body,
            [[r - n + 0.0005, h - e], [r - n + 0.0005, h], [r - n - w, h], [r - n - w, h - lid], [0.0, h - lid]],
        ]
    )
    return S.finish(S.revolve(S.rounded(S.solid_profile(prof), 0.0006), 72))


def box(rng: np.random.Generator) -> trimesh.Trimesh:
    """Rounded-edge cuboid (cereal, sugar, gelatin or tea box); sides 3-30 cm, standing or lying on a face."""
    kind = rng.choice(["cereal", "small", "any"])
    if kind == "cereal":
        dims = [rng.uniform(0.14, 0.22), rng.uniform(0.04, 0.09), rng.uniform(0.18, 0.30)]
    elif kind == "small":
        dims = sorted(rng.uniform(0.03, 0.16, 3))
    else:
        dims = sorted(np.exp(rng.uniform(np.log(0.03), np.log(0.3), 3)))
    if kind != "cereal":
        dims[2] = max(dims[2], 0.05)
        dims = [dims[i] for i in rng.permutation(3)]
    r = rng.uniform(0.001, min(0.006, 0.2 * min(dims)))
    return S.finish(S.rounded_box((dims[0], dims[1], dims[2]), r, 32))


def spray_bottle(rng: np.random.Generator) -> trimesh.Trimesh:
    """Trigger spray bottle: an oval or round body with a shoulder and collar, a sprayer head with a nozzle
    pointing +x and a trigger tab under it; 20-30 cm tall."""
    h = rng.uniform(0.20, 0.30)
    rc, collar_h = rng.uniform(0.013, 0.019), rng.uniform(0.012, 0.022)
    col_h, shroud_h = rng.uniform(0.025, 0.04), rng.uniform(0.022, 0.035)
    body_h = h - collar_h - col_h - shroud_h
    r_body = rng.uniform(0.03, 0.05)
    prof, z0, z1 = _bottle_profile(rng, body_h + collar_h, r_body, rc - 0.002, collar_h * 0.3, collar_h * 0.7, rc)
    m = _reshape(
        S.revolve(S.solid_profile(prof)), rng.uniform(0.5, 0.9), rng.choice([2.0, rng.uniform(2.5, 4)]), z0, z1
    )
    zt = body_h + collar_h  # top of the screw collar
    cw = 2 * rc * rng.uniform(0.75, 0.95)
    column = S.rounded_box((cw, cw, col_h + 0.004), 0.004, 16).translate((0, 0, zt + col_h / 2 - 0.002))
    tab_x, gap = rng.uniform(0.007, 0.011), rng.uniform(0.004, 0.009)
    x0 = cw / 2 + gap + tab_x / 2  # the trigger hangs in front of the column, above the collar
    back = cw / 2 + rng.uniform(0.0, 0.01)
    length = max(rng.uniform(0.06, 0.09), back + x0 + tab_x / 2 + 0.008)
    front = length - back
    shroud = S.rounded_box((length, cw * rng.uniform(0.9, 1.25), shroud_h), min(0.008, 0.3 * shroud_h), 16)
    z_shroud = zt + col_h + shroud_h / 2 - 0.001
    head = column + shroud.translate((length / 2 - back, 0, z_shroud))
    nr = rng.uniform(0.004, 0.007)
    nozzle = mf.Manifold.cylinder(rng.uniform(0.006, 0.014), nr, nr * 0.8, 24).rotate((0, 90, 0))
    nozzle = nozzle.translate((front - 0.003, 0, z_shroud + rng.uniform(-0.3, 0.3) * (shroud_h / 2 - nr)))
    tl = col_h * rng.uniform(0.6, 0.9)
    tab = S.rounded_box((tab_x, cw * 0.7, 0.006), 0.0025, 12)
    trigger = mf.Manifold.batch_hull(
        [
            tab.translate((x0, 0, zt + col_h + 0.004)),
            tab.translate((x0 + rng.uniform(0.0, 0.01), 0, zt + col_h - tl + 0.003)),
        ]
    )
    return S.finish(m + head + nozzle + trigger)


def drill(rng: np.random.Generator) -> trimesh.Trimesh:
    """Cordless power drill standing on its battery: a horizontal motor body with a chuck pointing +x,
    a raked pistol grip and a battery block; 15-25 cm long."""
    length = rng.uniform(0.15, 0.25)
    rb = rng.uniform(0.022, 0.032)
    bat = (rng.uniform(0.065, 0.10), rng.uniform(0.05, 0.075), rng.uniform(0.025, 0.04))
    grip_len, rake = rng.uniform(0.07, 0.10), np.radians(rng.uniform(5, 25))
    rg = rng.uniform(0.014, 0.018)
    battery = S.rounded_box(bat, 0.006, 24).translate((0, 0, bat[2] / 2))
    g0 = np.array([0.0, 0.0, bat[2] - 0.01])
    g1 = g0 + [grip_len * np.sin(rake), 0, grip_len * np.cos(rake)]
    z_axis = g1[2] + rb * 0.6
    grip = S.tube([g0, g1 + [0, 0, rb * 0.3]], rg, 40, (rng.uniform(1.1, 1.4), 0.8, 1.0))
    chuck_len = rng.uniform(0.03, 0.05)
    body_len = length - chuck_len
    x_rear = g1[0] - rg - body_len * rng.uniform(0.05, 0.25)
    rear = mf.Manifold.sphere(rb, 48).scale((rng.uniform(0.5, 0.9), 1, 1)).translate((x_rear + rb, 0, 0))
    front_r = rb * rng.uniform(0.75, 0.95)
    barrel = mf.Manifold.cylinder(body_len - rb, rb, front_r, 48).rotate((0, 90, 0)).translate((x_rear + rb, 0, 0))
    body = mf.Manifold.batch_hull([rear, barrel])
    rc = front_r * rng.uniform(0.55, 0.75)
    tip, step = rc * rng.uniform(0.45, 0.7), rng.uniform(0.3, 0.5)
    chuck = S.revolve(
        S.solid_profile(
            [
                [0.0, 0.0],
                [rc, 0],
                [rc, step * chuck_len],
                [rc * 0.9, (step + 0.05) * chuck_len],
                [rc * 0.9, 0.8 * chuck_len],
                [tip, chuck_len],
                [0, chuck_len],
            ]
        ),
        48,
    )
    chuck = chuck.rotate((0, 90, 0))
    chuck = chuck.translate((x_rear + body_len - 0.002, 0, 0))
    trigger = S.rounded_box((0.012, 0.012, rng.uniform(0.02, 0.03)), 0.004, 12).translate(
        (g1[0] + rg * 0.9, 0, g1[2] - 0.012)
    )
    top = (body + chuck).translate((0, 0, z_axis))
    return S.finish(battery + grip + top + trigger, length)


def banana(rng: np.random.Generator) -> trimesh.Trimesh:
    """Curved, tapering fruit with a stalk, lying on its side (the arc in the x-y plane); 15-22 cm long."""
    arc = np.radians(rng.uniform(40, 85))
    radius = 1.0 / arc  # unit arc length; scaled to size at the end
    t = np.linspace(0, 1, 40)
    ang = -arc / 2 + arc * t
    pts = np.stack([radius * np.sin(ang), radius * (1 - np.cos(ang)), np.zeros_like(t)], 1)
    thick = rng.uniform(0.075, 0.11)
    rad = thick * np.maximum(np.sin(np.pi * np.clip(t * 1.04 - 0.01, 0, 1)) ** rng.uniform(0.4, 0.7), 0.22)
    tang = np.array([np.cos(ang[-1]), np.sin(ang[-1]), 0.0])
    stalk = pts[-1] + tang[None] * np.linspace(0.01, rng.uniform(0.05, 0.09), 5)[:, None]
    m = S.sweep(np.vstack([pts, stalk]), np.append(rad, np.full(5, thick * 0.2)), [0.0, 0.0, 1.0], 40)
    amp, centre = rng.uniform(0.03, 0.07), np.array([0.0, radius, 0.0])

    def ridges(v: Array) -> Array:  # rounded-pentagon cross-sections around the arc
        v = np.array(v, dtype=np.float64)
        d = v - centre
        rho = np.hypot(d[:, 0], d[:, 1])
        u = np.stack([d[:, 0], d[:, 1]], 1) / np.maximum(rho, 1e-12)[:, None]
        lr, lz = rho - radius, d[:, 2]
        k = 1 + amp * np.cos(5 * np.arctan2(lz, lr))
        v[:, :2] = centre[:2] + u * (radius + lr * k)[:, None]
        v[:, 2] = lz * k
        return v

    size = rng.uniform(0.15, 0.22)
    return S.finish(m.warp_batch(ridges), size)


def pitcher(rng: np.random.Generator) -> trimesh.Trimesh:
    """Tall hollow jug (wall 3-5 mm) with a pulled spout at +x and a handle at -x; 15-25 cm tall."""
    h, r = rng.uniform(0.15, 0.25), rng.uniform(0.045, 0.07)
    wall = rng.uniform(0.003, 0.005)
    knots_z = np.array([0.0, 0.3, 0.75, 1.0]) * h
    knots_r = np.array([rng.uniform(0.8, 1.0), 1.0, rng.uniform(0.75, 0.97), 0.0]) * r
    knots_r[3] = knots_r[2] * rng.uniform(1.0, 1.15)
    z = h * np.sin(np.linspace(0, np.pi / 2, 28))  # dense near the rim, where the spout is pulled
    outer = np.stack([PchipInterpolator(knots_z, knots_r)(z), z], 1)
    wall_cs, cavity = S.vessel(outer, wall, wall + rng.uniform(0, 0.004))
    body = S.revolve(wall_cs, 96)
    spout_h, push, width = rng.uniform(0.02, 0.045), rng.uniform(0.01, 0.022), rng.uniform(0.25, 0.5)

    def spout(v: Array) -> Array:
        v = np.array(v, dtype=np.float64)
        s = np.clip((v[:, 2] - (h - spout_h)) / spout_h, 0, 1) ** 2
        ang = np.arctan2(v[:, 1], v[:, 0])
        grow = 1 + push * s * np.exp(-((ang / width) ** 2)) / np.maximum(np.hypot(v[:, 0], v[:, 1]), 1e-9)
        v[:, 0] *= grow
        v[:, 1] *= grow
        return v

    bar = rng.uniform(0.006, 0.009)
    z_hi = h - bar - rng.uniform(0.008, 0.025)
    handle = S.handle(
        S.profile_radius(outer), rng.uniform(0.2, 0.45) * h, z_hi, rng.uniform(0.025, 0.04), bar, wall, rng, -1.0
    )
    return S.finish(body.warp_batch(spout) + (handle - S.revolve(cavity, 96)))


def jar(rng: np.random.Generator) -> trimesh.Trimesh:
    """Closed jar: a body with a rounded shoulder and a screw lid wider than its neck; 8-16 cm tall."""
    h = rng.uniform(0.08, 0.16)
    r = rng.uniform(0.03, min(0.06, 0.5 * h))
    rn = r * rng.uniform(0.75, 0.95)
    rl = rn + rng.uniform(0.002, 0.005)
    lid = rng.uniform(0.012, 0.025)
    shoulder = rng.uniform(0.005, 0.15 * h)
    z_sh = h - lid - rng.uniform(0.002, 0.006) - shoulder
    f = rng.uniform(0.003, 0.01)
    a = np.linspace(-np.pi / 2, 0, 6)
    s = np.linspace(0, 1, 8)
    prof = np.vstack(
        [
            [[0.0, 0.0]],
            np.stack([r - f + f * np.cos(a), f + f * np.sin(a)], 1),
            np.stack([rn + (r - rn) * np.cos(np.pi / 2 * s), z_sh + shoulder * s], 1),
            [[rn, h - lid], [rl, h - lid], [rl, h], [0.0, h]],
        ]
    )
    cs = S.rounded(S.solid_profile(prof), 0.0015)
    if rng.random() < 0.6:  # grip grooves on the lid
        g = mf.CrossSection.circle(0.0008, 8)
        for zg in np.linspace(h - lid, h, rng.integers(3, 6))[1:-1]:
            cs = cs - g.translate((rl, zg)) - g.translate((-rl, zg))
    return S.finish(S.revolve(cs, 80))


def fruit(rng: np.random.Generator) -> trimesh.Trimesh:
    """Apple, orange, lemon or pear: a lumpy revolved or ellipsoidal solid; largest side 6-11 cm."""
    kind = rng.choice(["apple", "orange", "lemon", "pear"])
    phi = np.linspace(0, np.pi, 40)
    if kind == "orange":
        m = mf.Manifold.sphere(1.0, 64).scale((1, 1, rng.uniform(0.85, 1.0)))
        size = rng.uniform(0.06, 0.10)
    elif kind == "lemon":
        m = mf.Manifold.sphere(1.0, 64).scale((1.0, 0.72, 0.72))
        tip = rng.uniform(0.08, 0.2)

        def pinch(v: Array) -> Array:  # pointed ends along x
            v = np.array(v, dtype=np.float64)
            e = np.clip((np.abs(v[:, 0]) - 0.55) / 0.45, 0, 1) ** 2
            v[:, 1:] *= (1 - 0.45 * e)[:, None]
            v[:, 0] *= 1 + tip * e
            return v

        m = m.warp_batch(pinch)
        size = rng.uniform(0.07, 0.10)
    elif kind == "apple":
        rho = 1 + rng.uniform(0.03, 0.12) * -np.cos(phi)
        dip = rng.uniform(0.1, 0.25) * np.exp(-(((np.pi - phi) / 0.35) ** 2)) + 0.08 * np.exp(-((phi / 0.3) ** 2))
        zp = -rho * np.cos(phi) - dip * np.sign(-np.cos(phi))
        prof = np.stack([rho * np.sin(phi), zp], 1)
        prof[[0, -1], 0] = 0.0
        m = S.revolve(S.solid_profile(prof), 64)
        top = float(prof[-1, 1])
        m = m + mf.Manifold.cylinder(rng.uniform(0.15, 0.3), 0.04, 0.03, 12).translate((0, 0, top - 0.05))
        m = m.scale((1, 1, rng.uniform(0.85, 0.95)))
        size = rng.uniform(0.065, 0.10)
    else:
        u = (1 - np.cos(np.linspace(0, np.pi, 48))) / 2  # 0..1, dense at the ends
        h = 2 * rng.uniform(1.2, 1.6)  # height; the widest radius is about 1
        neck = np.clip((u - rng.uniform(0.3, 0.4)) / rng.uniform(0.35, 0.5), 0, 1)
        rz = 2 * np.sqrt(u * (1 - u)) * (1 - rng.uniform(0.35, 0.55) * (3 * neck**2 - 2 * neck**3))
        z = u * h
        m = S.revolve(S.solid_profile(np.stack([rz, z], 1)), 64)
        m = m + mf.Manifold.cylinder(0.3, 0.05, 0.035, 12).translate((0, 0, h - 0.05))
        size = rng.uniform(0.08, 0.11)
    return S.finish(S.radial_noise(m, rng, rng.uniform(0.01, 0.03)), size)


def tool(rng: np.random.Generator) -> trimesh.Trimesh:
    """Hammer, screwdriver or spatula lying flat, handle along x; 15-30 cm long."""
    kind = rng.choice(["hammer", "screwdriver", "spatula"])
    size = rng.uniform(0.15, 0.30)
    if kind == "hammer":  # unit-free sketch, scaled to `size` (the handle's length) at the end
        ry, rz = rng.uniform(0.045, 0.065), rng.uniform(0.035, 0.05)
        handle = S.tube([[0.0, 0.0, 0.0], [1.0, 0, 0]], ry, 24, (1.0, 1.0, rz / ry))
        hw, hl = rng.uniform(0.08, 0.11), rng.uniform(0.35, 0.5)
        face = mf.Manifold.cylinder(hl * 0.55, hw * 0.7, hw * 0.6, 32).rotate((-90, 0, 0))
        claw = S.rounded_box((hw * 1.2, hl * 0.5, hw * 0.9), 0.01, 12).translate((0, -hl * 0.2, 0))
        head = (face + claw).translate((1.0, hl * 0.2, 0))
        m = handle + head
    elif kind == "screwdriver":
        hlen, hr = rng.uniform(0.3, 0.45), rng.uniform(0.05, 0.075)
        sr = rng.uniform(0.012, 0.018)
        zz = np.linspace(0, hlen, 14)
        bulge = hr * (1 + 0.12 * np.sin(np.pi * zz / hlen))
        bulge[[0, -1]] *= 0.85
        prof = np.vstack([[[0.0, 0.0]], np.stack([bulge, zz], 1), [[0.0, hlen]]])
        hnd = S.revolve(S.rounded(S.solid_profile(prof), 0.01), 64)
        flutes = rng.uniform(0.03, 0.07)

        def flute(v: Array) -> Array:
            v = np.array(v, dtype=np.float64)
            k = 1 + flutes * np.cos(6 * np.arctan2(v[:, 1], v[:, 0]))
            v[:, :2] *= k[:, None]
            return v

        shaft = mf.Manifold.cylinder(1.0 - hlen, sr, sr, 24).translate((0, 0, hlen - 0.01))
        tip = mf.Manifold.cylinder(0.04, sr, sr * 0.3, 24).scale((1.6, 0.35, 1)).translate((0, 0, 0.99))
        m = (hnd.warp_batch(flute) + shaft + tip).rotate((0, 90, 0))
    else:
        hlen = rng.uniform(0.5, 0.65)
        hy = rng.uniform(0.04, 0.06)
        handle = S.tube([[0.0, 0.0, 0.0], [hlen, 0, 0]], hy, 24, (1.0, 1.0, rng.uniform(0.5, 0.8)))
        bw, bl, bt = rng.uniform(0.2, 0.35), 1.0 - hlen - 0.1, rng.uniform(0.012, 0.02)
        blade = S.rounded_box((bl, bw, bt), bt * 0.45, 12).translate((1.0 - bl / 2, 0, -0.03))
        neck = S.tube([[hlen - 0.02, 0, 0], [1.0 - bl + 0.02, 0, -0.03]], 0.02, 16, (1.0, 1.0, 0.6))
        m = handle + neck + blade
    return S.finish(m, size)


FAMILIES: dict[str, Callable[[np.random.Generator], trimesh.Trimesh]] = {
    "mug": mug,
    "cup": cup,
    "bowl": bowl,
    "plate": plate,
    "bottle": bottle,
    "can": can,
    "box": box,
    "spray_bottle": spray_bottle,
    "drill": drill,
    "banana": banana,
    "pitcher": pitcher,
    "jar": jar,
    "fruit": fruit,
    "tool": tool,
}
KINDS: tuple[str, ...] = tuple(FAMILIES)


def names(kinds: tuple[str, ...], start: int, stop: int) -> list[str]:
    """The catalogue-style names ``household/<kind>_<index>`` of objects ``start`` .. ``stop - 1`` of
    each of ``kinds`` (the catalogue lists the first ``catalogue.HOUSEHOLD_PER_KIND``; later indices
    are extra shapes generated by name)."""
    return [f"household/{k}_{i:03d}" for k in kinds for i in range(start, stop)]


def make(kind: str, index: int) -> trimesh.Trimesh:
    """Object ``index`` of family ``kind`` (one of :data:`KINDS`), deterministic; metres, z up, resting on z = 0."""
    if kind not in FAMILIES:
        raise KeyError(f"unknown household kind {kind!r}; one of {', '.join(KINDS)}")
    return FAMILIES[kind](np.random.default_rng(S.seed(kind, index)))
