"""Regression gates on speed and memory (``evsmap gate``, ``nox -s gates``).

Every workload - each registered network's forward pass (torch and ONNX Runtime), each map
updater's ``integrate`` on real TUM frames, ``evsmap map`` end to end, the readers, the report
build - runs in a fresh process that measures three things:

* ``time_ratio``: the workload's time divided by a fixed calibration workload timed in the same
  process, alternating with it (:mod:`evsmap.gate.calibration`), so machine speed and its drift
  cancel and one baseline holds on machines of the same kind;
* ``peak_rss_bytes``: the process's peak resident memory over the workload, less the footprint
  of the process idle just before it (every plug-in imported) and less the pages of mapped
  files (library code) the workload brought in, whose number follows the page cache, not the
  code (:mod:`evsmap.measure.memory`);
* exact counts (parameters, FLOPs, octree nodes, file bytes, a hash of a seeded output).

:mod:`evsmap.gate.compare` holds them against a committed baseline
(``benchmarks/baseline.json``): counts must match, a time ratio may not grow by more than 15 %
nor a peak by more than 10 %. See ``docs/gates.md``.
"""
