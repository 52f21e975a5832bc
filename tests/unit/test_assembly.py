"""Assemblies: random unions of primitives that training data can name, apart from the catalogue."""

import numpy as np
import pytest

from shapeviewer.sim import assembly, catalogue

INDICES = range(40)


def test_assemblies_are_placed_single_solids_of_varied_shape():
    meshes = [assembly.make("parts", i) for i in INDICES]
    for m in meshes:
        assert m.is_watertight and m.is_winding_consistent and m.volume > 0
        assert len(m.split(only_watertight=False)) == 1
        assert assembly.SIZE[0] - 1e-6 <= m.extents.max() <= assembly.SIZE[1] + 1e-6
        assert m.bounds[0, 2] == pytest.approx(0.0, abs=1e-9)
        np.testing.assert_allclose(m.bounds[:, :2].mean(0), 0.0, atol=1e-9)
    # Not one kind in disguise: how much of its box each fills ranges from rods to blocks.
    fill = np.array([m.volume / np.prod(m.extents) for m in meshes])
    assert fill.min() < 0.1 and fill.max() > 0.5
    # Some are hollow or pierced: their volume is well under that of their convex hull.
    assert sum(m.volume < 0.5 * m.convex_hull.volume for m in meshes) >= 5
    np.testing.assert_array_equal(assembly.make("parts", 3).vertices, meshes[3].vertices)  # deterministic


def test_hollow_assemblies_are_open_thin_walled_vessels():
    for i in range(12):
        m = assembly.make("hollow", i)
        # One shell (a cavity closed inside would be a second one) holding far less than its hull: the
        # cavity is open to the outside, as a vessel's is.
        assert m.is_watertight and len(m.split(only_watertight=False)) == 1
        assert m.volume < 0.8 * m.convex_hull.volume
        assert assembly.SIZE[0] - 1e-6 <= m.extents.max() <= assembly.SIZE[1] + 1e-6


def test_assemblies_resolve_by_name_but_are_not_listed():
    assert not any(e.name.startswith("assembly/") for e in catalogue.catalogue())
    name = "assembly/parts_007"
    assert catalogue.shape_kind(name) == "parts"
    assert catalogue.shape_kind("assembly/hollow_007") == "hollow"
    np.testing.assert_array_equal(catalogue.load_mesh(name).faces, assembly.make("parts", 7).faces)
    splits = [catalogue.model_split(n) for n in assembly.names()]
    assert 0.05 < splits.count("holdout_model") / len(splits) < 0.3  # validation models, as for household
    with pytest.raises(KeyError):
        catalogue.load_mesh(f"assembly/parts_{assembly.PER_KIND:03d}")
    with pytest.raises(KeyError):
        assembly.make("mug", 0)
