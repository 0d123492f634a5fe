"""Systems EVSMaP is compared with: ESANet-R34-NBt1D and FC-HarDNet-70 (segmenters), the
networks of Tables I and II (:mod:`baselines.networks`, docs/baselines.md), the classic
semantic octree of semantic_slam and the C++ OctoMap (map updaters, registered by
:mod:`baselines.updaters`)."""

import evsmap  # noqa: F401, I001 - first: it keys the compiled kernels by their code
from baselines import networks as _networks  # noqa: F401  (registers the plug-ins)
from baselines import segmenters as _segmenters  # noqa: F401
from baselines import updaters as _updaters  # noqa: F401
