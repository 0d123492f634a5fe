"""Poses from a bag's transform messages: timestamped samples of one transform, a track that
resamples them at a frame's time (linear translation, slerp rotation, a ``max_pose_gap`` check)
and the ``/tf`` + ``/tf_static`` tree that chains static and dynamic links from one frame to
another."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from evsmap.errors import DataFormatError
from evsmap.geometry import interpolate_poses, pose_matrix
from evsmap.readers.rosbag.messages import _fmt, _frame_name, _stamp_ns

BODY_TO_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0],
                            [0.0, 0.0, 0.0, 1.0]])
"""Pose of a ROS optical frame (z forward, x right, y down) in its body frame (x forward, y left,
z up): appended to image poses with ``camera_axes="body"``."""


class _NoPose(Exception):
    """No pose at a frame's stamp (message without the stamp)."""



@dataclass
class _Samples:
    """Timestamped transforms parent <- child (pose of child in parent)."""

    parent: str
    child: str
    label: str
    times: list[int] = field(default_factory=list)  # ns
    bag_times: list[int] = field(default_factory=list)
    trans: list[tuple[float, float, float]] = field(default_factory=list)
    quats: list[tuple[float, float, float, float]] = field(default_factory=list)

    def add(self, stamp: int, log: int, t: Any, q: Any) -> None:
        self.times.append(stamp)
        self.bag_times.append(log)
        self.trans.append((float(t.x), float(t.y), float(t.z)))
        self.quats.append((float(q.x), float(q.y), float(q.z), float(q.w)))

    def track(self, source: str) -> _Track:
        return _Track(self, source)


class _Track:
    """A dynamic transform resampled at query times (lerp + slerp between samples)."""

    def __init__(self, samples: _Samples, source: str) -> None:
        ns = np.asarray(samples.bag_times if source == "bag" else samples.times, dtype=np.int64)
        trans = np.asarray(samples.trans, dtype=np.float64).reshape(-1, 3)
        quats = np.asarray(samples.quats, dtype=np.float64).reshape(-1, 4)
        order = np.argsort(ns, kind="stable")
        ns, trans, quats = ns[order], trans[order], quats[order]
        # several samples at one stamp: keep the last
        keep = np.ones(len(ns), dtype=bool)
        keep[:-1] = ns[1:] != ns[:-1]
        self.ns, self.trans, self.quats = ns[keep], trans[keep], quats[keep]
        self.times = self.ns.astype(np.float64) * 1e-9
        self.label = samples.label
        self.samples = samples

    def __len__(self) -> int:
        return len(self.ns)

    def covers(self, t_ns: int, max_gap: float) -> bool:
        try:
            self.check(t_ns, max_gap)
        except _NoPose:
            return False
        return True

    def check(self, t_ns: int, max_gap: float) -> None:
        ns = self.ns
        if not len(ns) or t_ns < ns[0] or t_ns > ns[-1]:
            span = f"{_fmt(int(ns[0]))} .. {_fmt(int(ns[-1]))}" if len(ns) else "no samples"
            raise _NoPose(f"outside the samples of {self.label} ({span})")
        i = int(np.searchsorted(ns, t_ns))
        gap = abs(int(ns[i]) - t_ns)
        if i > 0:
            gap = min(gap, t_ns - int(ns[i - 1]))
        if gap * 1e-9 > max_gap:
            raise _NoPose(f"the nearest sample of {self.label} is {gap * 1e-9:.3f} s away "
                          f"(max_pose_gap {max_gap} s)")

    def at(self, t_ns: int, max_gap: float) -> np.ndarray:
        self.check(t_ns, max_gap)
        return interpolate_poses(self.times, self.trans, self.quats,
                                 np.array([t_ns * 1e-9]))[0]


def _check_quat(q: Any, where: str) -> None:
    v = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
    with np.errstate(over="ignore"):
        norm = np.linalg.norm(v)
    if not np.all(np.isfinite(v)) or not np.isfinite(norm) or norm < 1e-6:
        raise DataFormatError(f"{where}: invalid rotation quaternion {v.tolist()}")


def _check_translation(t: Any, where: str) -> None:
    v = np.array([t.x, t.y, t.z], dtype=np.float64)
    if not np.all(np.isfinite(v)):
        raise DataFormatError(f"{where}: non-finite translation {v.tolist()}")


class _TfTree:
    """``/tf`` + ``/tf_static``: a tree of frames; looks up world <- sensor at a time."""

    def __init__(self, label: str) -> None:
        self.label = label
        self.static: dict[str, tuple[str, np.ndarray]] = {}
        self.dynamic: dict[str, _Samples] = {}
        self.conflicts: set[str] = set()
        self.tracks: dict[str, _Track] = {}
        self.source = "header"

    def add(self, tf: Any, log: int, topic: str, static: bool) -> None:
        parent, child = _frame_name(tf.header.frame_id), _frame_name(tf.child_frame_id)
        where = f"{self.label}: topic {topic} transform {parent} -> {child}"
        _check_quat(tf.transform.rotation, where)
        _check_translation(tf.transform.translation, where)
        t, q = tf.transform.translation, tf.transform.rotation
        if static:
            self.static[child] = (parent, pose_matrix(
                np.array([t.x, t.y, t.z], dtype=np.float64),
                np.array([q.x, q.y, q.z, q.w], dtype=np.float64)))
            return
        samples = self.dynamic.get(child)
        if samples is None:
            samples = self.dynamic[child] = _Samples(parent, child, f"{topic} {parent} -> {child}")
        elif samples.parent != parent:
            self.conflicts.add(child)
            return
        samples.add(_stamp_ns(tf), log, t, q)

    def set_source(self, source: str) -> None:
        self.source = source
        self.tracks = {c: s.track(source) for c, s in self.dynamic.items()}

    def parent(self, frame: str) -> str | None:
        if frame in self.static:
            return self.static[frame][0]
        if frame in self.dynamic:
            return self.dynamic[frame].parent
        return None

    def frames(self) -> set[str]:
        out = set(self.static) | set(self.dynamic)
        out |= {p for p, _ in self.static.values()} | {s.parent for s in self.dynamic.values()}
        return out

    def to_root(self, frame: str) -> list[str]:
        path, seen = [frame], {frame}
        while (p := self.parent(path[-1])) is not None and p not in seen:
            path.append(p)
            seen.add(p)
        return path

    def root(self, frame: str) -> str:
        return self.to_root(frame)[-1]

    def chain(self, target: str, source: str) -> tuple[list[str], list[str]] | None:
        """Frames from ``source`` up to the common ancestor and from ``target`` up to it."""
        up_s, up_t = self.to_root(source), self.to_root(target)
        common = next((f for f in up_s if f in set(up_t)), None)
        if common is None:
            return None
        return up_s[: up_s.index(common) + 1], up_t[: up_t.index(common) + 1]

    def _edge(self, child: str, t_ns: int, max_gap: float) -> np.ndarray:
        if child in self.static:
            return self.static[child][1]
        return self.tracks[child].at(t_ns, max_gap)

    def _up(self, path: list[str], t_ns: int, max_gap: float) -> np.ndarray:
        out = np.eye(4)
        for child in reversed(path[:-1]):  # ancestor-most link first
            out = out @ self._edge(child, t_ns, max_gap)
        return out

    def lookup(self, target: str, source: str, t_ns: int, max_gap: float) -> np.ndarray:
        """Pose of ``source`` in ``target`` at ``t_ns`` (raises _NoPose)."""
        links = self.chain(target, source)
        if links is None:
            raise _NoPose(f"no transform chain from {target} to {source}")
        up_s, up_t = links
        return np.linalg.inv(self._up(up_t, t_ns, max_gap)) @ self._up(up_s, t_ns, max_gap)

    def dynamic_links(self, target: str, source: str) -> list[str]:
        links = self.chain(target, source)
        if links is None:
            return []
        return [c for path in links for c in path[:-1] if c not in self.static]

    def describe(self, target: str, source: str) -> str:
        links = self.chain(target, source)
        if links is None:
            return "none"
        up_s, up_t = links
        path = up_t + up_s[::-1][1:]  # target up to the common ancestor, then down to source
        marks = []
        for a, b in zip(path, path[1:], strict=False):
            child = a if self.parent(a) == b else b
            marks.append(f"{a} -> {b} ({'static' if child in self.static else 'dynamic'})")
        return ", ".join(marks) if marks else "identity"
