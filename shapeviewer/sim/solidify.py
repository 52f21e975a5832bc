"""Mesh repair for catalogue objects: a mesh file or triangle soup made one watertight solid in metres
(duplicate vertices merged, stray slivers dropped, closed parts united with manifold3d)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh


def union_parts(parts: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Boolean union of closed parts with manifold3d (overlapping convex pieces -> one solid)."""
    import manifold3d as mf

    solids = []
    for p in parts:
        m = mf.Manifold(
            mf.Mesh(vert_properties=np.asarray(p.vertices, np.float32), tri_verts=np.asarray(p.faces, np.uint32))
        )
        if m.status() == mf.Error.NoError and not m.is_empty():
            solids.append(m)
    if not solids:
        raise ValueError("no part is a closed manifold")
    out = mf.Manifold.batch_boolean(solids, mf.OpType.Add).to_mesh()
    return trimesh.Trimesh(np.asarray(out.vert_properties)[:, :3], np.asarray(out.tri_verts), process=True)


def process_mesh(path: Path, scale: tuple) -> trimesh.Trimesh:
    """Load a mesh file and make it a watertight solid in metres, or raise ValueError saying why."""
    mesh = trimesh.load(path, force="mesh", process=True)
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError("no triangles")
    return make_solid(mesh, scale)


def make_solid(mesh: trimesh.Trimesh, scale: tuple = (1.0, 1.0, 1.0)) -> trimesh.Trimesh:
    """``mesh`` scaled per axis by ``scale`` and repaired into one watertight solid of positive volume
    (duplicate vertices merged, stray slivers dropped, closed parts united), or ValueError saying why."""
    if len(mesh.faces) == 0:
        raise ValueError("no triangles")
    if not np.all(np.isfinite(mesh.vertices)):
        raise ValueError("non-finite vertices")
    mesh = trimesh.Trimesh(mesh.vertices * np.asarray(scale, dtype=np.float64), mesh.faces, process=True)
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    # Stray slivers (YCB scans) and loose pieces: keep real bodies only.
    parts = [p for p in mesh.split(only_watertight=False) if len(p.faces) > 10] or [mesh]
    if len(parts) == 1 and parts[0].is_watertight:
        solid = parts[0]
    else:
        solid = union_parts(parts) if all(p.is_watertight for p in parts) else parts[0]
        if len(parts) > 1 and not solid.is_watertight:
            raise ValueError("parts are not closed")
    if not solid.is_watertight:
        raise ValueError("not watertight")
    if solid.volume < 0:
        solid.invert()
    if solid.volume <= 0:
        raise ValueError("zero volume")
    return solid
