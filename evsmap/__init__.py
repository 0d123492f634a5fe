"""evsmap: the open benchmark harness of EVSMaP (README.md)."""

from evsmap.mapping import jit_cache as _jit_cache

_jit_cache.install()  # first, before any kernel module: compiled kernels keyed by their code
