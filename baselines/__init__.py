"""Systems EVSMaP is compared with: ESANet-R34-NBt1D and FC-HarDNet-70 (segmenters)."""

from baselines import segmenters as _segmenters  # noqa: F401  (registers the plug-ins)
