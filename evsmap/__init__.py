"""evsmap: the EVSMaP benchmark harness (docs/index.md)."""

from evsmap.mapping import jit_cache as _jit_cache

_jit_cache.install()  # first, before any kernel module: compiled kernels keyed by their code
