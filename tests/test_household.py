"""Procedural household objects: valid solids of the documented sizes, hollow vessels, catalogue entries."""

from collections import Counter

import numpy as np
import pytest

from shapeviewer.geometry import raycasting_scene
from shapeviewer.sim import catalogue, household, solids

INDICES = (0, 1, 7)
HOLLOW = ("mug", "cup", "bowl", "pitcher")


@pytest.fixture(scope="module")
def meshes():
    return {(k, i): household.make(k, i) for k in household.KINDS for i in INDICES}


def first_hit_z(mesh, x: float, y: float) -> float:
    """Height of the first surface a ray straight down through (x, y) meets."""
    import open3d as o3d

    scene = raycasting_scene(mesh)
    top = mesh.bounds[1, 2] + 1.0
    t = scene.cast_rays(o3d.core.Tensor(np.array([[x, y, top, 0, 0, -1]], np.float32)))["t_hit"].numpy()[0]
    return float(top - t)


def test_there_are_at_least_the_fourteen_families():
    assert len(household.KINDS) >= 14
    assert set(household.KINDS) == set(household.SIZE_RANGE)


@pytest.mark.parametrize("kind", household.KINDS)
def test_every_family_makes_valid_solids_of_its_size(kind, meshes):
    lo, hi = household.SIZE_RANGE[kind]
    for i in INDICES:
        m = meshes[kind, i]
        assert m.is_watertight and m.is_winding_consistent, (kind, i)
        assert m.volume > 0, (kind, i)
        assert len(m.split(only_watertight=False)) == 1, (kind, i)
        assert solids.MIN_FACES <= len(m.faces) <= solids.MAX_FACES, (kind, i, len(m.faces))
        assert lo - 1e-6 <= m.extents.max() <= hi + 1e-6, (kind, i, m.extents)
        # object frame: resting on z = 0, bounding box centred on the x-y origin
        assert m.bounds[0, 2] == pytest.approx(0.0, abs=1e-9)
        np.testing.assert_allclose(m.bounds[:, :2].mean(0), 0.0, atol=1e-9)
    # proportions vary with the index
    assert len({tuple(np.round(meshes[kind, i].extents, 4)) for i in INDICES}) == len(INDICES)


@pytest.mark.parametrize("kind", household.KINDS)
def test_same_name_same_mesh(kind, meshes):
    again = household.make(kind, INDICES[1])
    np.testing.assert_array_equal(again.vertices, meshes[kind, INDICES[1]].vertices)
    np.testing.assert_array_equal(again.faces, meshes[kind, INDICES[1]].faces)


@pytest.mark.parametrize("kind", HOLLOW)
def test_vessels_are_open_thin_walled_shells(kind, meshes):
    for i in INDICES:
        m = meshes[kind, i]
        assert m.volume < 0.6 * m.convex_hull.volume, (kind, i)
        # looking down the middle, the first surface is the floor, not a lid
        assert first_hit_z(m, 0.0, 0.0) < 0.25 * m.extents[2], (kind, i)


@pytest.mark.parametrize("kind", ("mug", "pitcher"))
def test_handles_make_a_loop_fused_to_the_wall(kind, meshes):
    for i in INDICES:
        m = meshes[kind, i]
        assert m.euler_number == 0, (kind, i)  # genus 1: one through-hole, the handle's loop
        assert len(m.split(only_watertight=False)) == 1


def test_closed_shapes_have_no_handle_loop(meshes):
    for (kind, i), m in meshes.items():
        if kind not in ("mug", "pitcher"):
            assert m.euler_number == 2, (kind, i)


def test_unknown_kind_is_refused():
    with pytest.raises(KeyError):
        household.make("teapot", 0)


def test_catalogue_lists_every_kind_with_both_splits():
    entries = [e for e in catalogue.catalogue() if e.source == "household"]
    assert len(entries) == len(household.KINDS) * catalogue.HOUSEHOLD_PER_KIND
    splits = Counter((catalogue.shape_kind(e.name), e.split) for e in entries)
    for kind in household.KINDS:
        assert splits[kind, "train"] > 0 and splits[kind, "holdout_model"] > 0, kind
    assert 0.1 < sum(e.split == "holdout_model" for e in entries) / len(entries) < 0.2
    e = catalogue.entry("household/mug_003")
    assert e.path == "household:mug/3" and e.scale == (1.0, 1.0, 1.0) and e.split == catalogue.model_split(e.name)
    assert catalogue.view_split("household/mug_003", 5) in ("training_view", "holdout_view", "holdout_model")
    # the rest of the catalogue is still there
    assert any(x.source == "ycb" for x in catalogue.catalogue()) and any(
        x.name.startswith("random/") for x in catalogue.catalogue()
    )


def test_load_mesh_builds_and_caches(tmp_path, monkeypatch):
    monkeypatch.setenv("SHAPEVIEWER_CACHE", str(tmp_path))
    m = catalogue.load_mesh("household/mug_003")
    assert m.is_watertight and m.euler_number == 0
    assert catalogue._cache_path("household/mug_003").exists()
    cached = catalogue.load_mesh("household/mug_003")
    np.testing.assert_array_equal(cached.vertices, m.vertices)
    np.testing.assert_array_equal(cached.faces, m.faces)
    e = catalogue.entry("household/mug_003")
    assert len(m.faces) == e.faces
    np.testing.assert_allclose(m.extents, e.extents, atol=1e-6)
    with pytest.raises(KeyError):
        catalogue.load_mesh(f"household/mug_{catalogue.HOUSEHOLD_PER_KIND:03d}")


def test_shape_kind():
    assert catalogue.shape_kind("ycb/025_mug") == "mug"
    assert catalogue.shape_kind("ycb/003_cracker_box") == "box"
    assert catalogue.shape_kind("ycb/035_power_drill") == "drill"
    assert catalogue.shape_kind("ycb/011_banana") == "banana"
    assert catalogue.shape_kind("household/drill_001") == "drill"
    assert catalogue.shape_kind("household/spray_bottle_012") == "spray_bottle"
    assert catalogue.shape_kind("random/042") == "random"
    assert catalogue.shape_kind("pybullet/mug") == "mug"
    assert catalogue.shape_kind("pybullet/duck") == "other"
    ycb = [e.name for e in catalogue.catalogue() if e.source == "ycb"]
    assert len(ycb) == 78
    assert all(n.partition("/")[2] in catalogue.YCB_KIND for n in ycb)
    kinds = {catalogue.shape_kind(n) for n in ycb}
    assert set(household.KINDS) - {"jar"} <= kinds  # every household family but jar has a YCB counterpart
