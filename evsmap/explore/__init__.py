"""``evsmap explore``: a multi-objective search over a map updater's design space (docs/explore.md).

* :mod:`~evsmap.explore.space` - the search space as data (a TOML file: parameters, their
  ranges and the paper's defaults, the objectives the sampler steers by);
* :mod:`~evsmap.explore.bench` - one trial measured the way Table IV measures a map: the map's
  sizes, its 3D accuracy and mIoU against ground truth, its update rate as a ratio to OctoMap
  C++ timed in the same process, and the paired baseline map at the same shared settings;
* :mod:`~evsmap.explore.study` - the Optuna study: its RDB storage (an SQLite file in the study
  folder by default) and what it was made with;
* :mod:`~evsmap.explore.sampler` - the seeded sampler whose draws depend only on the stored
  trials (so a resumed study equals a straight one);
* :mod:`~evsmap.explore.workers` - the worker loop, and the trials of workers that died;
* :mod:`~evsmap.explore.run` - a study made or resumed and run here or on Ray, with progress;
* :mod:`~evsmap.explore.results` - the trials as plain records, the Pareto fronts and the
  answer to "where is the map smaller than the baseline's at no more than 1 point of 3D mIoU
  lost";
* :mod:`~evsmap.explore.latest` - where the latest study is, for ``evsmap reproduce``.

The report layer (:mod:`evsmap.report.explore`) writes the CSV, the plots and ``index.md``.
"""
