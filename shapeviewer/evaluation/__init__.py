"""The paper's evaluation (Tables I-V), one module per job:

* :mod:`.viewsets`: the test views (the paper's three view sets, tabletop views) and their renders.
* :mod:`.run`: per-view completions and grasps, the runner (local processes or Ray), the sample store;
  :func:`.run.evaluate` is ``shapeviewer.evaluate``.
* :mod:`.methods`: the completion methods' one vocabulary (:data:`.methods.Method`, names, keys, titles).
* :mod:`.records`: the files of a results folder: view stems, view records (read, write, parse),
  completion rows (:class:`.records.CompletionRow`), grasp rows.
* :mod:`.paper`: the paper's figures (Tables I-V).
* :mod:`.tables`: the summaries and every rendering of the tables (markdown, CSV).
* :mod:`.results_index`: the SQLite index of a results folder and its sync.
* :mod:`.results`: :class:`.results.ResultsStore`, the read API of a results folder.
* :mod:`.summaries`: the plain records the store's read API returns.
"""
