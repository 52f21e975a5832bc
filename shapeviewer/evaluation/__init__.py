"""The paper's evaluation (Tables I-V), one module per job:

* :mod:`.viewsets`: the test views (the paper's three view sets, tabletop views) and their renders.
* :mod:`.run`: per-view completions and grasps, the runner (local processes or Ray), the sample store;
  :func:`.run.evaluate` is ``shapeviewer.evaluate``.
* :mod:`.records`: the files of a results folder: view stems, view records (read, write, parse), grasp rows.
* :mod:`.tables`: the paper's figures, the summaries and every rendering of the tables (markdown, CSV).
* :mod:`.results`: :class:`.results.ResultsStore`, the SQLite index and read API of a results folder.
* :mod:`.summaries`: the plain records the store's read API returns.
"""
