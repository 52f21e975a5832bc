"""Objects from folders of URDF files (scanned household objects): catalogue entries, repair, split,
kinds, the ``objects`` command and training data of them.

Tests marked with the ``clutter_objects`` fixture use the user's own object folders and skip without
them; the others build small URDF folders of their own.
"""

from __future__ import annotations

import logging
import os
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import trimesh

from shapeviewer.cli.commands import main
from shapeviewer.sim import catalogue, urdf_objects
from shapeviewer.sim import kinds as kind_names
from shapeviewer.training.generate import GenerationConfig, generate

URDF = """<?xml version="1.0"?>
<robot name="{name}">
  <link name="base_link">
    <inertial><mass value="{mass}"/></inertial>
    <visual>
      <origin xyz="{xyz}" rpy="{rpy}"/>
      <geometry><mesh filename="{mesh}" scale="{scale}"/></geometry>
    </visual>
  </link>
</robot>
"""


def write_object(folder: Path, name: str, mesh: trimesh.Trimesh | None, **urdf) -> Path:
    """``folder/name.urdf`` naming ``name_visual.obj`` (written from ``mesh`` unless None)."""
    folder.mkdir(parents=True, exist_ok=True)
    if mesh is not None:
        mesh.export(folder / f"{name}_visual.obj")
    fields = {"mass": "0.2", "xyz": "0 0 0", "rpy": "0 0 0", "scale": "1 1 1", "mesh": f"{name}_visual.obj"}
    path = folder / f"{name}.urdf"
    path.write_text(URDF.format(name=name, **{**fields, **urdf}))
    return path


@pytest.fixture
def own_cache(tmp_path, monkeypatch):
    """A cache folder of the test's own, so made-up folders leave nothing in the user's cache."""
    monkeypatch.setenv("SHAPEVIEWER_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv(catalogue.OBJECTS_ENV, raising=False)
    return tmp_path / "cache"


@pytest.fixture(scope="module")
def clutter_catalogue(clutter_objects):
    """``(entries of the folders, seconds to build the catalogue with them)``."""
    import time

    t0 = time.perf_counter()
    entries = catalogue.catalogue(objects_dirs=clutter_objects)
    return [e for e in entries if e.source == "urdf"], time.perf_counter() - t0


# ----------------------------------------------------------------------------------------------
# The user's own folders


def test_the_folders_objects_are_catalogue_entries_of_their_sizes(clutter_objects, clutter_catalogue):
    entries, seconds = clutter_catalogue
    files = sum(len(urdf_objects.urdf_files(f)) for f in clutter_objects)
    skipped = sum(len(catalogue.urdf_skipped(f)) for f in clutter_objects)
    assert len(entries) + skipped == files and len(entries) >= 0.9 * files
    sets = {urdf_objects.set_name(f) for f in clutter_objects}
    assert len(sets) == len(clutter_objects)  # two folders named "train" are two sets
    assert {e.name.split("/")[1] for e in entries} == sets
    for e in entries:
        assert e.split in ("train", "holdout_model") and e.split == catalogue.model_split(e.name)
        assert Path(e.path).is_file() and e.path.endswith(".urdf")
    # A few objects load as solids of a hand-held object's size (3-30 cm), the entry's extents.
    for e in entries[:: max(1, len(entries) // 6)]:
        with catalogue.objects_from(clutter_objects):  # by name: found in the folders in use
            mesh = catalogue.load_mesh(e.name)
        assert 0.03 <= mesh.extents.max() <= 0.30, (e.name, mesh.extents)
        np.testing.assert_allclose(mesh.extents, e.extents, atol=1e-6)
        assert mesh.is_watertight and mesh.volume > 0
    print(f"{len(entries)}/{files} objects in {seconds:.1f} s")


def test_every_listed_mesh_is_a_watertight_solid(clutter_catalogue):
    entries, _ = clutter_catalogue
    for e in entries:
        mesh = catalogue.load_mesh(e)
        assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0, e.name
        assert len(mesh.faces) == e.faces, e.name


def test_the_split_holds_out_about_fifteen_percent_and_one_object_has_one_split(clutter_catalogue):
    entries, _ = clutter_catalogue
    share = np.mean([e.split == "holdout_model" for e in entries])
    assert 0.08 <= share <= 0.25, share
    by_stem: dict[str, set[str]] = {}
    for e in entries:
        by_stem.setdefault(e.name.rpartition("/")[2], set()).add(e.split)
    assert all(len(splits) == 1 for splits in by_stem.values())  # same object in two sets: one split
    catalogue.clear_caches()  # read again (from the cached index): the same splits
    again = {e.name: e.split for e in catalogue.catalogue(objects_dirs=sorted({Path(e.path).parent for e in entries}))}
    assert all(again[e.name] == e.split for e in entries)


def test_kinds_are_told_by_the_objects_names(clutter_catalogue):
    entries, _ = clutter_catalogue
    kinds = Counter(catalogue.shape_kind(e.name) for e in entries)
    assert set(kinds) <= set(catalogue.YCB_KIND.values()) | set(kind_names.KIND_WORD.values()) | {"fruit", "banana"}
    assert sum(n for k, n in kinds.items() if k != "other") >= 0.25 * len(entries)
    print(dict(kinds.most_common()))


def test_objects_lists_the_folders_objects_with_split_source_and_kind(clutter_objects, capsys):
    args = ["objects"] + [a for f in clutter_objects for a in ("--objects-dir", str(f))]
    assert main(args) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.startswith("urdf/")]
    entries = [e for e in catalogue.catalogue(objects_dirs=clutter_objects) if e.source == "urdf"]
    assert len(rows) == len(entries)
    split = {e.name: e.split for e in entries}
    for row in rows:
        assert row[1] == split[row[0]] and row[2] == "urdf" and row[3] == catalogue.shape_kind(row[0])
    for f in clutter_objects:
        assert f"{f}: " in out
    assert os.environ.get(catalogue.OBJECTS_ENV) is None  # the command's folders are not left behind
    # without the option the listing is the shipped catalogue
    assert main(["objects"]) == 0
    assert "urdf/" not in capsys.readouterr().out


def test_generate_renders_a_tabletop_view_of_an_object(clutter_objects, clutter_catalogue, tmp_path):
    entries, _ = clutter_catalogue
    name = next(e.name for e in entries if catalogue.shape_kind(e.name) == "mug")
    r = generate(
        tmp_path / "data",
        GenerationConfig(views=1, scenes="tabletop"),
        objects=[name],
        workers=1,
        progress=False,
        objects_dirs=clutter_objects,
    )
    assert r["errors"] == [] and r["new_views"] == 1
    shard = tmp_path / "data" / "shards" / (name.replace("/", "__") + ".npz")
    with np.load(shard) as z:
        x, y = np.unpackbits(z["x"][0]).astype(bool), np.unpackbits(z["y"][0]).astype(bool)
    assert x.sum() >= 100 and y.sum() > x.sum()
    assert os.environ.get(catalogue.OBJECTS_ENV) is None


# ----------------------------------------------------------------------------------------------
# Folders made here


def test_a_urdf_scale_origin_and_mass_are_applied(tmp_path, own_cache):
    folder = tmp_path / "shelf"
    box = trimesh.creation.box(extents=(0.02, 0.03, 0.04))
    write_object(folder, "tall_box", box, scale="2 2 2", rpy=f"{np.pi / 2} 0 0", xyz="0.5 0 0", mass="0.35")
    (obj,), skipped = urdf_objects.scan(folder)
    assert skipped == [] and obj.name == "urdf/shelf/tall_box" and obj.mass == pytest.approx(0.35)
    (e,) = catalogue.catalogue(objects_dirs=[folder])[-1:]
    assert e.name == obj.name and e.source == "urdf" and e.path == str(folder.resolve() / "tall_box.urdf")
    # scaled x2, then rolled 90 degrees about x: y and z swap
    np.testing.assert_allclose(e.extents, (0.04, 0.08, 0.06), atol=1e-9)
    mesh = catalogue.load_mesh(e)
    np.testing.assert_allclose(mesh.bounds.mean(0), (0.5, 0, 0), atol=1e-9)  # the origin's offset
    with catalogue.objects_from([folder]):
        np.testing.assert_allclose(catalogue.centred_mesh(e.name).bounds.mean(0), 0, atol=1e-9)


def test_broken_objects_are_skipped_each_with_its_reason(tmp_path, own_cache, caplog):
    folder = tmp_path / "objects" / "train"
    write_object(folder, "good_can", trimesh.creation.cylinder(radius=0.03, height=0.1))
    tube = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=32)
    tube.update_faces(np.abs(tube.face_normals[:, 2]) < 0.5)  # no ends: two holes too large to close
    write_object(folder, "open_tube", tube)
    write_object(folder, "no_mesh", None)
    write_object(folder, "huge_box", trimesh.creation.box(extents=(2.0, 1.0, 1.0)))
    (folder / "not_xml.urdf").write_text("<robot><link>")
    with caplog.at_level(logging.WARNING):
        entries = [e for e in catalogue.catalogue(objects_dirs=[folder]) if e.source == "urdf"]
    assert [e.name for e in entries] == ["urdf/objects-train/good_can"]  # a split's folder: named with its parent
    reasons = dict(catalogue.urdf_skipped(folder))
    assert set(reasons) == {
        "no_mesh.urdf",
        "not_xml.urdf",
        "urdf/objects-train/open_tube",
        "urdf/objects-train/huge_box",
    }
    assert "not found" in reasons["no_mesh.urdf"] and "not a URDF" in reasons["not_xml.urdf"]
    assert "watertight" in reasons["urdf/objects-train/open_tube"]
    assert "not graspable" in reasons["urdf/objects-train/huge_box"]
    for what in reasons:
        assert any(what in r.getMessage() for r in caplog.records), what


def test_the_catalogue_without_a_folder_is_the_shipped_one(tmp_path, own_cache, monkeypatch):
    folder = tmp_path / "mine"
    write_object(folder, "red_cup", trimesh.creation.cylinder(radius=0.04, height=0.1))
    shipped = catalogue.catalogue()
    assert not any(e.source == "urdf" for e in shipped)
    with_folder = catalogue.catalogue(objects_dirs=[folder])
    assert with_folder[: len(shipped)] == shipped and [e.name for e in with_folder[len(shipped) :]] == [
        "urdf/mine/red_cup"
    ]
    assert catalogue.catalogue() == shipped  # the cached catalogue with the folder is not the default one
    with pytest.raises(KeyError, match="--objects-dir"):
        catalogue.load_mesh("urdf/mine/red_cup")
    with catalogue.objects_from([folder]):
        assert catalogue.catalogue() == with_folder
        assert catalogue.entry("urdf/mine/red_cup").split == catalogue.model_split("urdf/mine/red_cup")
        assert catalogue.load_mesh("urdf/mine/red_cup").is_watertight
    assert catalogue.catalogue() == shipped
    monkeypatch.setenv(catalogue.OBJECTS_ENV, str(folder))
    assert catalogue.catalogue() == with_folder


def test_a_folder_that_is_not_one_is_refused_with_a_clear_error(tmp_path, own_cache, capsys):
    assert main(["objects", "--objects-dir", str(tmp_path / "missing")]) == 2
    assert "not a folder" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["objects", "--objects-dir", str(tmp_path / "empty")]) == 2
    assert "no *.urdf files" in capsys.readouterr().err
    for parent in ("a", "b"):
        write_object(tmp_path / parent / "set", "cup", trimesh.creation.cylinder(radius=0.04, height=0.1))
    with pytest.raises(ValueError, match="both give the set name"):
        catalogue.object_dirs([tmp_path / "a" / "set", tmp_path / "b" / "set"])


def test_the_split_rule_is_fixed_by_the_objects_file_name():
    # The documented rule (15 % by a hash of urdf/<NAME>): these splits never change.
    assert catalogue.model_split("urdf/any/bravo") == "holdout_model"
    assert catalogue.model_split("urdf/any/foxtrot") == "holdout_model"
    assert catalogue.model_split("urdf/any/alpha") == "train"
    assert catalogue.model_split("urdf/other/alpha") == "train"
    # An object named as a YCB object has the YCB object's split.
    assert catalogue.model_split("urdf/any/mustard_bottle") == catalogue.model_split("ycb/006_mustard_bottle")
    assert catalogue.model_split("urdf/any/power_drill") == "holdout_model"
    assert catalogue.model_split("urdf/any/mug") == catalogue.model_split("ycb/025_mug") == "train"


@pytest.mark.parametrize(
    ("name", "kind"),
    [
        ("tomato_soup_can", "can"),
        ("RedCup_800_tex", "cup"),
        ("bowl_poisson_005", "bowl"),
        ("detergent_bottle_poisson_001", "bottle"),
        ("spray_can_poisson_000", "spray_bottle"),
        ("HeringTin_800_tex", "can"),
        ("banana_poisson_001", "banana"),
        ("BellPepper_v1_L3", "fruit"),
        ("apple", "fruit"),
        ("nutrigrain_apple_cinnamon", "other"),
        ("watering_can_poisson_001", "other"),
        ("hammer_poisson_004", "tool"),
        ("0a1b2c3d4e5f", "other"),
    ],
)
def test_a_name_tells_the_kind(name, kind):
    assert catalogue.shape_kind(f"urdf/any/{name}") == kind


def test_a_ycb_objects_name_tells_its_ycb_kind():
    assert catalogue.shape_kind("urdf/any/sugar_box") == "box"
    assert catalogue.shape_kind("urdf/any/sponge") == "box"
    assert catalogue.shape_kind("urdf/any/padlock") == "other"
