"""Training of the segmentation networks (``evsmap train``): recipes as data
(:mod:`~evsmap.train.recipe`), augmented data over any labelled reader
(:mod:`~evsmap.train.data`), the loop with DDP and AMP (:mod:`~evsmap.train.loop`: its
set-up :mod:`~evsmap.train.setup`, the trainer :mod:`~evsmap.train.trainer` on
:mod:`~evsmap.train.engine`, its hooks :mod:`~evsmap.train.hooks`), checkpoints
and weights files with cards (:mod:`~evsmap.train.checkpoint`), the settings a resume repeats
(:mod:`~evsmap.train.settings`), encoder initialisation (:mod:`~evsmap.train.init`). See
``docs/training.md``.

Importing this package imports no torch; the submodules other than ``recipe``, ``options`` and
``engine`` do.
"""
