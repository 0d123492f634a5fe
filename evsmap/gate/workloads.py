"""The workloads a gate times and measures, one :class:`Job` each.

A job's constructor loads its inputs (frames, observations, an ONNX file) - the process's idle
footprint is taken after it. :meth:`Job.build` makes what the workload holds (a network, an
ONNX Runtime session) and counts toward its memory but not its time; :meth:`Job.run` is the
timed unit; :meth:`Job.counts` returns the exact figures of the last run.

Names:

* ``net/<segmenter>/torch``, ``net/<segmenter>/onnxruntime``: one forward pass of every
  registered network (``module`` not None) at 480x640, batch 1, seeded weights and inputs;
* ``update/<updater>/5cm``, ``update/<updater>/2cm``: every registered updater integrating
  10 real TUM fr1_xyz frames (every 4th of the 37) into a fresh map, max range 4 m, with the
  top-3 of the seeded FEAGNet-V1 computed beforehand;
* ``map/feagnet-v1+multiclass-bayes``: ``evsmap map``'s pipeline end to end (reading, the
  seeded FEAGNet-V1 on torch, the update, the written file) on the first 10 TUM frames at 5 cm;
* ``read/tum``, ``read/rosbag``: opening and reading every frame of the TUM sample and of the
  ROS 1 lidar bag sample;
* ``report/build``: :func:`evsmap.report.build.build_report` on a stored run of
  ``evsmap reproduce`` (its records, shipped with evsmap).
"""

from __future__ import annotations

import abc
import fnmatch
import hashlib
import shutil
import tarfile
import tempfile
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from evsmap.errors import EvsmapError
from evsmap.mapping.options import OCTREE_DEFAULTS

if TYPE_CHECKING:  # torch is heavy to import; only type checkers need it here
    import torch

    from evsmap.interfaces import MapUpdater

NETWORK_SIZE = (480, 640)
RESOLUTIONS = {f"{OCTREE_DEFAULTS.resolution * 100:g}cm": OCTREE_DEFAULTS.resolution,
               "2cm": 0.02}
"""The leaf sizes every updater is gated at: the default (5 cm) and Table IV's 2 cm."""
MAX_RANGE = 4.0
UPDATE_FRAMES = tuple(range(0, 37, 4))
"""TUM fr1_xyz frames every updater integrates: every 4th of the 37, across the trajectory."""
MAP_FRAMES = 10
MAP_NETWORK = "feagnet-v1"
MAP_UPDATER = "multiclass-bayes"
TUM_TOLERANCE = 0.021  # s: the association tolerance that keeps all 37 frames
REPORT_FIXTURE = Path(__file__).with_name("fixtures") / "report-run.tar.gz"


@dataclass(frozen=True)
class Workload:
    """One gated workload: ``name`` (see the module docstring), ``kind`` (``net``,
    ``update``, ``map``, ``read``, ``report``), what it does, ``needs``: the inputs of the
    gate context it cannot run without (``tum``, ``bag``, ``observations``, ``onnx``), and the
    kind of calibration its time is divided by (:data:`evsmap.gate.calibration.KINDS`)."""

    name: str
    kind: str
    description: str
    needs: tuple[str, ...] = ()
    calibration: str = "compute"


def digest(*parts: Any) -> str:
    """sha256 (first 16 hex digits) of arrays (their dtype, shape and bytes) and strings."""
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            a = np.ascontiguousarray(part)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        elif isinstance(part, bytes):
            h.update(part)
        else:
            h.update(str(part).encode())
        h.update(b"\0")
    return h.hexdigest()[:16]


def plan(context: dict[str, Any]) -> list[Workload]:
    """Every workload of this installation: one per network and backend, per updater and
    resolution, plus the end-to-end map, the readers and the report build; on a GPU
    (``context["device"]``), each network's forward pass there (the GPU's workloads)."""
    device = context.get("device", "cpu")
    if device != "cpu":
        return [Workload(f"net/{name}/torch", "net",
                         f"{name}: one forward pass on torch (eager) on {device}, 480x640",
                         calibration="gpu")
                for name in sorted(context.get("networks", {}))]
    out = []
    for name in sorted(context.get("networks", {})):
        out.append(Workload(f"net/{name}/torch", "net",
                            f"{name}: one forward pass on torch (eager), 480x640"))
        out.append(Workload(f"net/{name}/onnxruntime", "net",
                            f"{name}: one forward pass on ONNX Runtime (CPU), 480x640",
                            needs=("onnx",)))
    for name in context.get("updaters", []):
        for tag, res in RESOLUTIONS.items():
            out.append(Workload(f"update/{name}/{tag}", "update",
                                f"{name}: integrate {len(UPDATE_FRAMES)} TUM frames at "
                                f"{res:g} m", needs=("tum", "observations"),
                                calibration="memory"))
    out.append(Workload(f"map/{MAP_NETWORK}+{MAP_UPDATER}", "map",
                        f"evsmap map's pipeline: {MAP_FRAMES} TUM frames, {MAP_NETWORK} "
                        f"(torch), {MAP_UPDATER} at {OCTREE_DEFAULTS.resolution:g} m, the map file "
                        f"written",
                        needs=("tum",)))
    out.append(Workload("read/tum", "read", "open the TUM fr1_xyz sample and read its 37 frames",
                        needs=("tum",)))
    out.append(Workload("read/rosbag", "read", "open the ROS 1 lidar bag sample and read its "
                        "clouds", needs=("bag",), calibration="memory"))
    out.append(Workload("report/build", "report", "build the report of a stored reproduce run",
                        calibration="memory"))
    return out


# -- selection ----------------------------------------------------------------------------------


def select(workloads: Sequence[Workload], patterns: Sequence[str] | None) -> list[Workload]:
    """The workloads whose name matches one of ``patterns`` (exact names or shell patterns,
    ``net/*``); all of them without patterns.

    Raises:
        EvsmapError: a pattern matches no workload (names the pattern and the known ones).
    """
    if not patterns:
        return list(workloads)
    chosen = []
    for pattern in patterns:
        hit = [w for w in workloads if fnmatch.fnmatchcase(w.name, pattern)]
        if not hit:
            known = ", ".join(w.name for w in workloads)
            raise EvsmapError(f"--only {pattern!r} matches no gate workload (known: {known})")
        chosen += [w for w in hit if w not in chosen]
    return chosen


def selected_names(names: Iterable[str], patterns: Sequence[str] | None) -> set[str]:
    return {n for n in names
            if not patterns or any(fnmatch.fnmatchcase(n, p) for p in patterns)}


class Job(abc.ABC):
    """A workload's timed unit; see the module docstring for the phases."""

    def warm(self) -> None:
        """Before the idle footprint: compile what is compiled on first use (numba kernels,
        when their on-disk cache is cold) on a small input, so the compiler's memory is not
        counted as the workload's and a cold cache measures like a warm one."""
        return None

    def build(self) -> None:
        """What the workload holds while it runs (counted in its memory, not timed)."""
        return None

    @abc.abstractmethod
    def run(self) -> None:
        """The timed unit."""

    def counts(self) -> dict[str, Any]:
        return {}


_T = TypeVar("_T")


def last_run(value: _T | None) -> _T:
    """What :meth:`Job.run` left (its output, its map); refuses a job that has not run."""
    if value is None:
        raise EvsmapError("a job's counts were asked for before it ran")
    return value


# -- networks -------------------------------------------------------------------------------


class TorchForward(Job):
    def __init__(self, name: str, context: dict[str, Any]) -> None:
        self.name = name
        self.device = context.get("device", "cpu")
        self.output: torch.Tensor | None = None

    def build(self) -> None:
        import torch

        from evsmap.registry import SEGMENTERS

        torch.manual_seed(0)
        self.segmenter = SEGMENTERS.create(self.name)
        if self.segmenter.module is None:
            raise EvsmapError(f"segmenter {self.name!r} is not a network")
        self.module = self.segmenter.module.eval().to(self.device)
        # evsmap.measure.pass_timing: cuDNN's autotuner on a GPU, as `evsmap speed` has it
        torch.backends.cudnn.benchmark = self.device != "cpu"
        self.inputs = tuple(t.to(self.device)
                            for t in self.segmenter.example_inputs(*NETWORK_SIZE))

    def run(self) -> None:
        import torch

        with torch.inference_mode():  # the worker's pass timer waits for the GPU
            self.output = self.module(*self.inputs)

    def counts(self) -> dict[str, Any]:
        from evsmap.measure.complexity import count_parameters, measure_complexity

        flops = measure_complexity(self.module, self.inputs).flops
        labels = last_run(self.output)[0].argmax(0).cpu().numpy().astype(np.int16)
        return {"params": count_parameters(self.module), "flops": int(flops),
                "output_sha256": digest(labels)}


class OnnxForward(Job):
    def __init__(self, name: str, context: dict[str, Any]) -> None:
        info = context["networks"][name]
        if not info.get("onnx"):
            raise EvsmapError(f"no ONNX export of {name}: {info.get('onnx_error', 'unknown')}")
        self.path = Path(info["onnx"])
        self.uses_depth = bool(info["uses_depth"])
        self.threads = int(context.get("threads", 1))
        self.output: np.ndarray | None = None

    def build(self) -> None:
        import onnxruntime as ort

        from evsmap.segmenters.network import seeded_inputs

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = self.threads
        opts.inter_op_num_threads = 1
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        self.session = ort.InferenceSession(str(self.path), opts,
                                            providers=["CPUExecutionProvider"])
        names = [i.name for i in self.session.get_inputs()]
        tensors = seeded_inputs(self.uses_depth, *NETWORK_SIZE)
        self.feeds = {n: t.numpy() for n, t in zip(names, tensors, strict=True)}

    def run(self) -> None:
        self.output = self.session.run(None, self.feeds)[0]

    def counts(self) -> dict[str, Any]:
        return {"onnx_bytes": self.path.stat().st_size,
                "output_sha256": digest(last_run(self.output)[0].argmax(0).astype(np.int16))}


# -- map updaters and the map command -----------------------------------------------------------


def tum_sequence(path: str):
    from evsmap.registry import READERS

    return READERS.create("tum", path=str(path), max_time_difference=TUM_TOLERANCE)


def load_observations(path: str | Path) -> list:
    from evsmap.data import SemanticObservation

    with np.load(path) as data:
        classes, probs, n = data["classes"], data["probs"], int(data["num_classes"])
    return [SemanticObservation(classes=classes[i], probs=probs[i], num_classes=n)
            for i in range(len(classes))]


class Integrate(Job):
    def __init__(self, name: str, resolution: float, context: dict[str, Any]) -> None:
        seq = tum_sequence(context["tum"])
        self.frames = [seq[i] for i in UPDATE_FRAMES]
        self.observations = load_observations(context["observations"])
        from evsmap.measure.engine import in_memory

        self.sequence = in_memory(self.frames, "tum-fr1-xyz (gate frames)")
        self.name = name
        self.resolution = resolution
        self.updater: MapUpdater | None = None

    def warm(self) -> None:
        from evsmap.registry import UPDATERS

        updater = UPDATERS.create(self.name, resolution=self.resolution, max_range=MAX_RANGE)
        semantic = updater.uses_semantics
        updater.integrate(self.frames[0], self.observations[0] if semantic else None)

    def run(self) -> None:
        from evsmap.measure.engine import run_mapping
        from evsmap.registry import UPDATERS

        self.updater = None  # the last map goes before the next is made
        # the measurement engine's loop, without its memory scope (the gate measures the
        # process's peak itself)
        self.updater = run_mapping(
            self.sequence,
            lambda: UPDATERS.create(self.name, resolution=self.resolution, max_range=MAX_RANGE),
            observations=self.observations, measure_memory=False).updater

    def counts(self) -> dict[str, Any]:
        from evsmap.measure.mapping import write_map

        updater = last_run(self.updater)
        stats = updater.stats()
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "map.ot"
            file_bytes = write_map(updater, path, "published")
            file_sha = digest(path.read_bytes())
        return {"nodes": int(stats.nodes), "leaves": int(stats.leaves),
                "file_bytes": int(file_bytes), "file_sha256": file_sha}


class MapCommand(Job):
    """``evsmap map``'s pipeline (:func:`evsmap.measure.mapping.map_sequence`, what the command
    runs): the TUM reader, the seeded FEAGNet-V1 on torch, the update and the map file. The
    command's own argument parsing and printing are left out: the gate sits below the command
    line (the layers contract in ``pyproject.toml``)."""

    def __init__(self, context: dict[str, Any]) -> None:
        self.tum = str(context["tum"])
        self.tmp = Path(tempfile.mkdtemp(prefix="evsmap-gate-map-"))
        self.record: Any = None
        self.frames = MAP_FRAMES

    def warm(self) -> None:
        self.frames = 1
        try:
            self.run()
        finally:
            self.frames = MAP_FRAMES

    def run(self) -> None:
        import torch

        from evsmap.measure.mapping import map_sequence
        from evsmap.registry import SEGMENTERS, UPDATERS

        self.record = None
        torch.manual_seed(0)  # the network's random weights
        segmenter = SEGMENTERS.create(MAP_NETWORK)
        updater = UPDATERS.create(MAP_UPDATER, resolution=OCTREE_DEFAULTS.resolution,
                                  max_range=MAX_RANGE)
        self.record = map_sequence(tum_sequence(self.tum), updater, updater_name=MAP_UPDATER,
                                   segmenter=segmenter, segmenter_name=MAP_NETWORK,
                                   frames=self.frames, out=self.tmp / "map.ot")

    def counts(self) -> dict[str, Any]:
        path = self.tmp / "map.ot"
        counts = {"frames": int(self.record.frames), "nodes": int(self.record.nodes),
                  "leaves": int(self.record.leaves), "file_bytes": path.stat().st_size,
                  "file_sha256": digest(path.read_bytes())}
        shutil.rmtree(self.tmp, ignore_errors=True)
        return counts


# -- readers and the report -----------------------------------------------------------------------


def frame_digest(frames: list) -> str:
    """A digest of every array a frame holds (RGB, depth, points and their colours, labels,
    pose, intrinsics)."""
    parts: list[Any] = []
    for f in frames:
        for key in ("rgb", "depth", "points", "point_colors", "labels", "pose", "intrinsics"):
            value = getattr(f, key, None)
            if value is not None and not callable(value):  # Frame.colors() is a method
                parts += [key, value if isinstance(value, np.ndarray) else repr(value)]
    return digest(*parts)


class ReadSequence(Job):
    def __init__(self, reader: str, context: dict[str, Any]) -> None:
        self.reader = reader
        self.path = str(context["tum" if reader == "tum" else "bag"])
        self.frames: list = []

    def run(self) -> None:
        from evsmap.registry import READERS

        self.frames = []
        with warnings.catch_warnings():  # the lidar bag's reader warns about its clouds
            warnings.simplefilter("ignore")
            if self.reader == "tum":
                seq = tum_sequence(self.path)
            else:
                seq = READERS.create(self.reader, path=self.path)
            self.frames = [seq[i] for i in range(len(seq))]

    def counts(self) -> dict[str, Any]:
        return {"frames": len(self.frames), "frames_sha256": frame_digest(self.frames)}


EMPTY_CACHE_WORKLOADS = frozenset({"report/build"})
"""Workloads whose worker gets an empty evsmap cache of its own (``EVSMAP_CACHE_DIR``, set by
the runner for this tree's and a reference's process alike): the report states the cache's
size, so it walks the whole cache, and a user's or the paired gate's own cache (a reference's
virtual environment is 56 000 files under ``gate/envs``) would time the disk, differently on
each side, rather than the report's code."""

REPORT_DIGESTED = ("table1.md", "table2.md", "table3.md", "table4.md", "table1.csv",
                   "table2.csv", "table3.csv", "table4.csv", "extra.csv")
"""Report files whose bytes are fixed by the records (index.md also states the cache size and
the PNGs the font renderer: neither is hashed)."""


class BuildReport(Job):
    def __init__(self, context: dict[str, Any]) -> None:
        self.run_dir = Path(tempfile.mkdtemp(prefix="evsmap-gate-report-"))
        with tarfile.open(context.get("report_fixture") or REPORT_FIXTURE) as tar:
            tar.extractall(self.run_dir, filter="data")
        self.written: list[Path] = []

    def run(self) -> None:
        from evsmap.report.build import build_report

        self.written = build_report(self.run_dir, study=None)  # not the cache's study

    def counts(self) -> dict[str, Any]:
        names = sorted(p.name for p in self.written)
        digested = [n for n in REPORT_DIGESTED if n in names]
        sha = digest(*[(self.run_dir / n).read_bytes() for n in digested])
        shutil.rmtree(self.run_dir, ignore_errors=True)
        return {"files": len(names), "tables_sha256": sha}


def make_job(name: str, context: dict[str, Any]) -> Job:
    """The job of workload ``name`` (loads its inputs)."""
    kind, _, rest = name.partition("/")
    if kind == "net":
        net, _, backend = rest.rpartition("/")
        if backend == "torch":
            return TorchForward(net, context)
        if backend == "onnxruntime":
            return OnnxForward(net, context)
    elif kind == "update":
        updater, _, tag = rest.rpartition("/")
        if tag in RESOLUTIONS:
            return Integrate(updater, RESOLUTIONS[tag], context)
    elif kind == "map" and rest == f"{MAP_NETWORK}+{MAP_UPDATER}":
        return MapCommand(context)
    elif kind == "read" and rest in ("tum", "rosbag"):
        return ReadSequence(rest, context)
    elif name == "report/build":
        return BuildReport(context)
    raise EvsmapError(f"unknown gate workload {name!r}")
