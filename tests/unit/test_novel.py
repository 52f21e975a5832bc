"""Novel kinds: valid solids that no training data can hold, yet render as tabletop test views."""

import numpy as np
import pytest

import shapeviewer as sv
from shapeviewer.evaluation.metrics import sampled_jaccard
from shapeviewer.sim import catalogue, household, novel
from shapeviewer.sim.tabletop import render_tabletop_view

INDICES = (0, 5)


@pytest.mark.parametrize("kind", novel.KINDS)
def test_every_novel_family_makes_placed_single_solids(kind):
    meshes = [novel.make(kind, i) for i in INDICES]
    for m in meshes:
        assert m.is_watertight and m.is_winding_consistent and m.volume > 0, kind
        assert len(m.split(only_watertight=False)) == 1, kind
        assert 0.05 <= m.extents.max() <= 0.31, (kind, m.extents)  # a size a hand can pick up
        assert m.bounds[0, 2] == pytest.approx(0.0, abs=1e-9)
        np.testing.assert_allclose(m.bounds[:, :2].mean(0), 0.0, atol=1e-9)
    assert not np.allclose(meshes[0].extents, meshes[1].extents)  # proportions vary with the index
    np.testing.assert_array_equal(novel.make(kind, INDICES[0]).vertices, meshes[0].vertices)  # deterministic


def test_novel_kinds_are_new_and_never_listed_for_training():
    assert not set(novel.KINDS) & set(household.KINDS)
    assert not any(e.name.startswith("novel/") for e in catalogue.catalogue())
    name = "novel/teapot_003"
    assert catalogue.model_split(name) == "holdout_model" and catalogue.shape_kind(name) == "teapot"
    np.testing.assert_array_equal(catalogue.load_mesh(name).faces, novel.make("teapot", 3).faces)
    with pytest.raises(KeyError):
        catalogue.load_mesh(f"novel/teapot_{novel.PER_KIND:03d}")
    with pytest.raises(KeyError):
        novel.make("mug", 0)


def test_a_novel_object_completes_from_its_tabletop_mask_better_than_its_hull():
    """What ``benchmarks/studies/novel_kinds.py`` does for one view: the ring's pixels and the table the
    segmentation found, completed through the public entry point into a closed mesh that overlaps
    the true ring more than the hull of its visible points does."""
    from shapeviewer.completion.baselines import hull_mesh

    v = render_tabletop_view("novel/ring_001", 10_007, seed=0)
    assert v is not None
    mask = v.capture.points_cam.reshape(-1, 3)[v.capture.labels.reshape(-1) == 0]
    mesh = sv.complete(mask, support_plane=v.plane_cam, mode="fast")
    truth = v.truth_cam()
    assert mesh.is_watertight
    assert sampled_jaccard(mesh, truth) > sampled_jaccard(hull_mesh(mask), truth) + 0.1
