"""The matrix's cells on a Ray cluster (``evsmap reproduce --executor ray [--address ADDR]``).

Ray is an optional extra (``pip install "evsmap[ray]"``), imported only when this executor is
made. How the cells are placed:

* A cell that is not timed is a Ray task that reserves the threads it uses (``num_cpus`` = the
  run's threads, at most the largest node's CPUs; the task sets torch to that many threads), so
  Ray runs as many side by side on a node as its CPUs hold.
* A timed cell is a task pinned to one node (``NodeAffinitySchedulingStrategy``) that reserves
  all of that node's CPUs, so no other task of the run (nor any task that asks for CPUs) runs
  beside it. Inside it the cell runs in a fresh spawned interpreter, as on this machine, and it
  uses all the node's CPUs as threads. One timed cell per node at a time.
* Timing nodes are the nodes like the head node (same CPU model and CPU count; without CPUs on
  the head, the largest such group), so every timed cell of a run is measured on the same kind
  of machine. The other nodes run only cells that are not timed.
* With ``reproduce --device cuda``, timing nodes are chosen among the nodes with a GPU Ray can
  reserve, alike by GPU model too, and a timed cell also reserves one GPU (``num_gpus=1``).
* Each record says where it ran: ``environment["host"]`` is the node's host name and
  ``environment["executor"]`` = ``{"name": "ray", "node_id", "cpus" (reserved),
  "whole_node"}`` (records written before named the host ``executor["node"]`` too).

The records themselves are written by the driver (:func:`evsmap.runner.matrix.run_matrix`) as
the tasks finish.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable
from concurrent.futures import Executor, Future
from typing import TYPE_CHECKING, Any, Literal

from evsmap.errors import EvsmapError
from evsmap.runner.executors import CellExecutor, TimingSlot, fresh_process

if TYPE_CHECKING:
    from evsmap.runner.context import RunContext

HEAD_RESOURCE = "node:__internal_head__"
"""The resource Ray gives its head node only."""

INSTALL_HINT = 'install it with pip install "evsmap[ray]"'


def import_ray() -> Any:
    """The ``ray`` module, or a one-line error saying how to install it."""
    try:
        import ray
    except ImportError:
        raise EvsmapError(f"--executor ray needs Ray, which is not installed: "
                          f"{INSTALL_HINT}") from None
    return ray


def check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Fail at once, in one line, when nothing answers at ``HOST:PORT`` (Ray itself retries
    for minutes); ``auto`` and other forms are left to Ray."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise EvsmapError(f"--executor ray: nothing answers at {address} "
                          f"({exc.strerror or exc}); start the cluster's head there with "
                          f"`ray start --head --port={port}`") from None


# ------------------------------------------------------------- run on the nodes (importable)
def _placed(result: dict[str, Any], cpus: int, whole_node: bool) -> dict[str, Any]:
    """``result`` (a record's dict) with where it ran: ``environment["host"]`` and
    ``environment["executor"]``."""
    import ray

    env = result.get("environment")
    if not isinstance(env, dict):
        env = result["environment"] = {}
    env["host"] = socket.gethostname()
    env["executor"] = {"name": "ray", "node_id": ray.get_runtime_context().get_node_id(),
                       "cpus": cpus, "whole_node": whole_node}
    return result


def _pooled_call(fn: Callable[..., dict[str, Any]], args: tuple[Any, ...],
                 cpus: int) -> dict[str, Any]:
    """A cell that is not timed, in a Ray worker, with as many torch threads as it reserved."""
    import torch

    torch.set_num_threads(cpus)
    return _placed(fn(*args), cpus, whole_node=False)


def _timed_call(fn: Callable[..., dict[str, Any]], args: tuple[Any, ...],
                cpus: int) -> dict[str, Any]:
    """A timed cell: the Ray task holds the whole node while the cell runs in a fresh
    interpreter (a Ray worker may have run other cells before; the spawned one has not)."""
    with fresh_process() as ex:
        result = ex.submit(fn, *args).result()
    return _placed(result, cpus, whole_node=True)


def _probe(paths: list[str]) -> dict[str, Any]:
    """What the driver checks on each node: its host, CPU model and instruction set and git
    commit (of :func:`~evsmap.environment.collect_environment`), its first GPU's model (empty
    without one), evsmap version and which of the run's ``paths`` it cannot see."""
    from pathlib import Path

    from evsmap.environment import collect_environment

    env = collect_environment()
    gpu = ""
    try:
        import torch

        if torch.cuda.is_available():
            gpu = torch.cuda.get_device_name(0)
    except Exception:  # noqa: BLE001 - a broken CUDA install is a node without a GPU
        gpu = ""
    return {**{k: env[k] for k in ("host", "cpu", "instruction_set", "git_commit")}, "gpu": gpu,
            "evsmap": env["versions"].get("evsmap", "unknown"),
            "missing": [p for p in paths if not Path(p).exists()]}


# ------------------------------------------------------------------------------ the driver
def timing_nodes(nodes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The nodes that time: those with the head node's CPU model, instruction set, CPU count
    and GPU model; when the head is not among ``nodes`` (it has no CPUs, or no GPU where the
    run times on one), the largest group of alike nodes (ties: the most CPUs, then the first
    listed). Each node: ``cpu``, ``cpus``, ``head`` and (optional) ``instruction_set`` and
    ``gpu``."""
    def kind(node: dict[str, Any]) -> tuple[str, str, int, str]:
        return node["cpu"], node.get("instruction_set", ""), node["cpus"], node.get("gpu", "")

    groups: dict[tuple[str, str, int, str], list[dict[str, Any]]] = {}
    for node in nodes:
        groups.setdefault(kind(node), []).append(node)
    head = next((n for n in nodes if n["head"]), None)
    if head is not None:
        return groups[kind(head)]
    return max(groups.values(), key=lambda g: (len(g), g[0]["cpus"]))


class _RayTasks(Executor):
    """A :class:`concurrent.futures.Executor` whose tasks are Ray tasks made by ``launch``; the
    futures complete as the tasks finish. Leaving it on an error cancels what is still
    running."""

    def __init__(self, ray: Any,
                 launch: Callable[[Callable[..., Any], tuple[Any, ...]], Any]) -> None:
        self._ray = ray
        self._launch = launch
        self._refs: list[Any] = []

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        if kwargs:
            raise TypeError("Ray cells take positional arguments only")
        ref = self._launch(fn, args)
        self._refs.append(ref)
        future: Future[Any] = ref.future()
        return future

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        refs, self._refs = self._refs, []
        if cancel_futures:
            for ref in refs:
                try:
                    self._ray.cancel(ref, recursive=True)
                except Exception:  # noqa: BLE001 - finished or already gone
                    pass
        elif wait and refs:
            self._ray.wait(refs, num_returns=len(refs))

    def __exit__(self, exc_type: object, *rest: object) -> Literal[False]:
        self.shutdown(wait=exc_type is None, cancel_futures=exc_type is not None)
        return False


class RayExecutor(CellExecutor):
    """Cells as Ray tasks (see the module's docstring for the placement).

    Args:
        address: the cluster to join (``HOST:6379``, or ``auto``: the cluster started on
            this machine with ``ray start``); it is left running at the end. None starts a
            local cluster, stopped at the end. A Ray already initialised in this process
            (``ray.init`` called by the caller) is used as it is and left as it is.
        num_cpus: the CPUs of a local cluster (default: this machine's).
    """

    name = "ray"

    def __init__(self, *, address: str | None = None, num_cpus: int | None = None) -> None:
        self._ray = import_ray()
        if address:
            check_reachable(address)
        self.address = address
        self.num_cpus = num_cpus or os.cpu_count() or 1
        self._own_session = False
        self._slots: list[TimingSlot] = []
        self._nodes: list[dict[str, Any]] = []
        self._max_cpus = 1
        self._prepared_for: list[str] | None = None
        self._gpu = False

    # -- session ---------------------------------------------------------------------------
    def __enter__(self) -> RayExecutor:
        ray = self._ray
        if not ray.is_initialized():
            try:
                if self.address:
                    ray.init(address=self.address, logging_level="WARNING")
                else:
                    ray.init(address="local", num_cpus=self.num_cpus, include_dashboard=False,
                             logging_level="WARNING")
            except (ConnectionError, RuntimeError, ValueError) as exc:
                what = (f"cannot connect to the cluster at {self.address}" if self.address
                        else "cannot start a local Ray cluster")
                raise EvsmapError(f"--executor ray: {what} ({exc})") from None
            self._own_session = True
        self._pooled = ray.remote(_pooled_call)
        self._timed = ray.remote(max_calls=1)(_timed_call)
        self._probe = ray.remote(num_cpus=0)(_probe)
        return self

    def close(self) -> None:
        # a local cluster started here stops; a joined cluster is only left
        if self._own_session and self._ray.is_initialized():
            self._ray.shutdown()
        self._own_session = False

    # -- nodes -----------------------------------------------------------------------------
    def prepare(self, ctx: RunContext) -> None:
        """Probe every node with CPUs: it must see the run folder, the data root and the
        weights folder at the driver's paths and run the driver's evsmap version; then choose
        the timing nodes."""
        from pathlib import Path

        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        from evsmap.version import evsmap_version

        if not hasattr(self, "_probe"):
            raise RuntimeError("RayExecutor.prepare() outside `with executor:`")
        paths = [p for p in (ctx.out, ctx.data_root, ctx.weights_dir) if p and Path(p).exists()]
        if self._prepared_for == paths:  # the CLI prepares first, to print the nodes
            return
        nodes = [n for n in self._ray.nodes()
                 if n.get("Alive") and n.get("Resources", {}).get("CPU", 0) >= 1]
        if not nodes:
            raise EvsmapError("--executor ray: the cluster has no live node with CPUs")
        refs = [self._probe.options(scheduling_strategy=NodeAffinitySchedulingStrategy(
            n["NodeID"], soft=False)).remote(paths) for n in nodes]
        probes = []
        for node, ref in zip(nodes, refs, strict=True):
            try:
                probes.append(self._ray.get(ref))
            except Exception as exc:  # noqa: BLE001 - e.g. evsmap is not installed there
                first = str(exc).strip().splitlines()[-1] if str(exc).strip() else repr(exc)
                raise EvsmapError(
                    f"--executor ray: node {node.get('NodeManagerHostname', node['NodeID'])} "
                    f"cannot run evsmap ({first}): install the same evsmap on every "
                    f"node") from None
        mine = evsmap_version()
        for probe in probes:
            if probe["missing"]:
                raise EvsmapError(
                    f"--executor ray: node {probe['host']} cannot see "
                    f"{', '.join(probe['missing'])}: every node needs the run folder (--out), "
                    f"the data root and the weights folder at the same paths (a shared file "
                    f"system)")
            if probe["evsmap"] != mine:
                raise EvsmapError(
                    f"--executor ray: node {probe['host']} runs evsmap {probe['evsmap']}, this "
                    f"machine {mine}: install the same evsmap on every node")
        self._nodes = [
            {"node_id": n["NodeID"], "host": p["host"], "cpu": p["cpu"],
             "instruction_set": p["instruction_set"], "git_commit": p["git_commit"],
             "gpu": p.get("gpu", ""), "gpus": int(n["Resources"].get("GPU", 0)),
             "cpus": int(n["Resources"]["CPU"]), "head": HEAD_RESOURCE in n["Resources"]}
            for n, p in zip(nodes, probes, strict=True)]
        self._max_cpus = max(n["cpus"] for n in self._nodes)
        self._gpu = ctx.device != "cpu"
        candidates = [n for n in self._nodes if n["gpus"] >= 1 and n["gpu"]] if self._gpu \
            else self._nodes
        if not candidates:
            raise EvsmapError(f"--executor ray --device {ctx.device}: no node of the cluster "
                              f"has a GPU Ray can reserve (start its nodes with GPUs, or time "
                              f"on the CPU)")
        chosen = timing_nodes(candidates)
        for node in self._nodes:
            node["times"] = node in chosen
        self._slots = [TimingSlot(name=n["host"], cpus=n["cpus"], node_id=n["node_id"])
                       for n in chosen]
        self._prepared_for = paths

    def timing_slots(self) -> list[TimingSlot]:
        if not self._slots:
            raise RuntimeError("RayExecutor.timing_slots() before prepare()")
        return list(self._slots)

    # -- tasks -----------------------------------------------------------------------------
    def pool_threads(self, threads: int) -> int:
        """At most the largest node's CPUs (a task asking for more would never run)."""
        return max(1, min(threads, self._max_cpus))

    def pool(self, workers: int, threads: int) -> Executor:
        """Ray decides how many run at once from the CPUs each reserves; ``workers`` is not
        used."""
        cpus = self.pool_threads(threads)
        task = self._pooled.options(num_cpus=cpus)
        return _RayTasks(self._ray, lambda fn, args: task.remote(fn, args, cpus))

    def fresh(self, slot: TimingSlot) -> Executor:
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        if slot.node_id is None or slot.cpus is None:
            raise ValueError(f"{slot.name}: not a Ray node")
        task = self._timed.options(
            num_cpus=slot.cpus, num_gpus=1 if self._gpu else 0,
            scheduling_strategy=NodeAffinitySchedulingStrategy(slot.node_id, soft=False))
        return _RayTasks(self._ray, lambda fn, args: task.remote(fn, args, slot.cpus))

    def describe(self) -> dict[str, Any]:
        return {"name": self.name,
                "address": self.address or ("local cluster" if self._own_session else None),
                "nodes": [dict(n) for n in self._nodes]}

    def summary(self) -> str:
        """One line for the run's output: the nodes, and which of them time."""
        timing = [n for n in self._nodes if n.get("times")]
        cpus = sum(n["cpus"] for n in self._nodes)
        where = self.address or ("a local cluster" if self._own_session
                                 else "the Ray this process had joined")
        first = timing[0] if timing else None
        kind = (f"{first['cpu']}, {first['instruction_set']}, {first['cpus']} CPUs"
                + (f", {first['gpu']}" if self._gpu and first.get("gpu") else "")
                if first else "none")
        return (f"ray ({where}): {len(self._nodes)} node(s), {cpus} CPUs; timed cells on "
                f"{len(timing)} node(s) ({kind}), each alone on its node")
