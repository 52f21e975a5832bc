"""The completion methods: one vocabulary for the evaluation, the results store and the viewer.

A method's :data:`Method` name is what results folders hold: mesh files
(``meshes/<stem>__<method>.ply``), completion rows, grasp entries and grasp files. Those strings
never change, so that old results folders still load. Everything else about a method is in
:data:`METHOD_INFO`: the Pipeline tab's short :data:`MeshKind` key (its mesh dropdowns, scene layer
``<key>_mesh``), the Dataset tab's column title, the narrow panel's short label and
the Pipeline tab's mesh title.

The methods, as the paper compares them (Fig. 1 order):

* ``Partial``: the observed points meshed as they are (:func:`completion.baselines.partial_mesh`).
* ``Mirror``: the points mirrored about the plane the paper's baseline finds (:func:`~.baselines.mirror_mesh`).
* ``Hull``: the convex hull of the points (:func:`~.baselines.hull_mesh`).
* ``Ours-fast``: marching cubes of the CNN output (the mean of its 8 sample completions).
* ``Ours-detailed``: Algorithm 1 on that output, the paper's one "Ours".
* ``Ours-envelope``: the grasp envelope of the CNN's sample completions
  (:func:`grasp.robust.envelope_mesh`); grasped, not scored as a completion in Tables I-III.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

Method = Literal["Partial", "Mirror", "Hull", "Ours-fast", "Ours-detailed", "Ours-envelope"]
# The Pipeline tab's keys, in its dropdown order (ours first: the fast mesh comes with every completion).
MeshKind = Literal["fast", "detailed", "envelope", "partial", "mirror", "hull"]


@dataclass(frozen=True)
class MethodInfo:
    """How a method is named, stored and shown.

    Attributes:
        method: the name in results folders (file names, rows, grasp entries).
        key: the Pipeline tab's short key (its mesh dropdowns, scene layer ``<key>_mesh``).
        title: the Dataset tab's column label.
        short: the narrow panels' label (the Dataset tab's summary tables).
        mesh_title: what the Pipeline tab calls the mesh of a segment.
        scored: a completion scored in Tables I-III (the grasp envelope is grasped only).
        cnn: made from the CNN's sample completions (its grasps can be ranked by robustness).
    """

    method: Method
    key: MeshKind
    title: str
    short: str
    mesh_title: str
    scored: bool = True
    cnn: bool = False


METHOD_INFO: dict[Method, MethodInfo] = {
    i.method: i
    for i in (
        MethodInfo("Partial", "partial", "Partial", "Part.", "Partial baseline"),
        MethodInfo("Mirror", "mirror", "Mirror", "Mirr.", "Mirror baseline"),
        MethodInfo("Hull", "hull", "Hull", "Hull", "Hull baseline"),
        MethodInfo("Ours-fast", "fast", "Ours (fast)", "Fast", "Fast mesh", cnn=True),
        MethodInfo("Ours-detailed", "detailed", "Ours (detailed)", "Det.", "Detailed mesh", cnn=True),
        MethodInfo("Ours-envelope", "envelope", "Ours (envelope)", "Env.", "Grasp envelope", scored=False, cnn=True),
    )
}
ALL_METHODS: tuple[Method, ...] = get_args(Method)
# The completions scored in Tables I-III, in the paper's Fig. 1 order.
METHODS: tuple[Method, ...] = tuple(m for m in ALL_METHODS if METHOD_INFO[m].scored)
ENVELOPE: Method = "Ours-envelope"
GRASP_TABLE_METHODS: tuple[Method, ...] = ALL_METHODS  # the columns of the grasp tables
CNN_METHODS: tuple[Method, ...] = tuple(m for m in ALL_METHODS if METHOD_INFO[m].cnn)
MESH_KINDS: tuple[MeshKind, ...] = get_args(MeshKind)
_BY_KEY: dict[str, Method] = {i.key: m for m, i in METHOD_INFO.items()}
_RANK: dict[str, int] = {m: i for i, m in enumerate(ALL_METHODS)}


def method_of(key: MeshKind) -> Method:
    """The method of a Pipeline-tab key: ``"fast"`` -> ``"Ours-fast"``."""
    return _BY_KEY[key]


def key_of(method: Method) -> MeshKind:
    """The Pipeline-tab key of a method: ``"Ours-fast"`` -> ``"fast"``."""
    return METHOD_INFO[method].key


def is_method(name: str) -> bool:
    """Whether ``name`` is one of :data:`ALL_METHODS` (a results folder may hold others)."""
    return name in METHOD_INFO


def method_rank(name: str) -> int:
    """Where a method sorts (:data:`ALL_METHODS` order; names the vocabulary does not know go last)."""
    return _RANK.get(name, len(_RANK))
