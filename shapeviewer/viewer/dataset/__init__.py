"""The Dataset tab: browse a results store (:mod:`shapeviewer.evaluation.results`) like the paper's website.

The tab lists the catalogue objects with their results, and shows one view at a time in 3D, left
to right as in the paper's Fig. 1: the ground truth, the partial view (points), then each method's
completion (Partial, Mirror, Ours-fast, Ours-detailed), each labelled with its metrics and, when
the store has them, its grasps (planned on the completion vs executed on the true object).

Frames. The store keeps every mesh in the camera optical frame of its view. For display, all of a
view's items share one *display frame*: the object's own frame (catalogue axes, z up), turned
about z so that the side the sensor did not see faces the browser camera, with the ground truth
standing on z = 0; each item is then shifted along +x into its column (:func:`layout_view`).

A session's 3D scene is shared by its two tabs (and the browser does not report tab changes), so
the dataset is drawn under its own root frame ``/dataset`` that is only visible while the dataset is
*shown*; showing it hides the pipeline's nodes and restores them afterwards (the app's
``set_pipeline_visible``). Selecting a view shows the dataset; "Back to the pipeline" and "Open in
pipeline" return. Until a view is selected nothing is chosen (the Object dropdown reads "(choose an
object)"), so the tab never names a view that the 3D scene does not show; "Open in pipeline" leaves
the dataset on screen while the capture loads and then brings the Pipeline tab to the front.

Every dropdown value a browser sends is checked against the dropdown's entries (a forged one is
refused with a notice); names from the store are escaped wherever they are shown as markdown.

One module per job: :mod:`.layout` (where things go, plain numpy), :mod:`.summary` (labels,
tables, the chart), :mod:`.controls` (the GUI), :mod:`.drawing` (scene nodes and cameras),
:mod:`.exports` (downloads), :mod:`.work` (background threads) and :mod:`.tab`, which ties them
together. Without a browser, tests call :meth:`DatasetTab.select`, :meth:`DatasetTab.step`,
:meth:`DatasetTab.export_bytes` and read :attr:`DatasetTab.drawn`.
"""

from .drawing import ROOT
from .layout import ViewLayout, layout_view
from .tab import DEFAULT, DatasetHooks, DatasetTab
from .work import SampleBuild

__all__ = ["DEFAULT", "ROOT", "DatasetHooks", "DatasetTab", "SampleBuild", "ViewLayout", "layout_view"]
