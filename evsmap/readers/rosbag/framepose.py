"""The pose of each frame: the mixin of :class:`~evsmap.readers.rosbag.sequence.RosbagSequence`
that sets up the pose source (a pose topic followed by the sensor offset, or a ``/tf`` chain from
the world frame to the sensor frame), chooses the time source (header stamps, bag time or message
order, with the reason recorded in ``meta``) and resolves every planned frame's pose or the
reason it has none."""

from __future__ import annotations

import warnings

import numpy as np

from evsmap.errors import DataFormatError, EvsmapError
from evsmap.geometry import pose_matrix
from evsmap.readers.rosbag.index import _IndexMixin, _Plan
from evsmap.readers.rosbag.messages import _fmt, _frame_name
from evsmap.readers.rosbag.poses import BODY_TO_OPTICAL, _NoPose


class _FramePoseMixin(_IndexMixin):
    """Pose source, time source and per-frame poses for an indexed, planned sequence."""

    def _poses(self, pose_topic, use_tf, world_frame, sensor_frame, sensor_offset,
               time_source) -> None:
        if not self._plans_for["header"] and not self._plans_for["bag"]:
            why = self._why_none(self._dropped_for["header"])
            raise DataFormatError(f"{self.label}: no frames ({why})")
        first = self._plans_for["header"][0].msgs[0] if self._plans_for["header"] else \
            self._plans_for["bag"][0].msgs[0]
        sensor = _frame_name(sensor_frame) if sensor_frame else (first.frame_id if first else "")
        self.meta["sensor_frame"] = sensor
        self._sensor_given = bool(sensor_frame)
        offset = None
        if sensor_offset is not None:
            offset = np.asarray(sensor_offset, dtype=np.float64)
            if offset.shape != (4, 4) or not np.all(np.isfinite(offset)):
                raise EvsmapError(f"sensor_offset must be a finite 4x4 matrix, got shape "
                                  f"{offset.shape}")
            u, _, vt = np.linalg.svd(offset[:3, :3])  # re-orthonormalise (rounded calibrations)
            offset = offset.copy()
            offset[:3, :3] = u @ vt
        if use_tf:
            self._setup_tf(world_frame, sensor, sensor_frame)
        else:
            self._setup_odom(pose_topic, sensor, sensor_frame, offset)
        if self.kind == "rgbd" and self.camera_axes == "body":
            self.meta["camera_axes"] = "body (body-to-optical rotation appended)"
        else:
            self.meta["camera_axes"] = "optical" if self.kind == "rgbd" else "sensor"

        chosen, reason = self._choose_time_source(time_source, use_tf)
        self.meta["time_source"] = chosen
        if reason:
            self.meta["time_source_reason"] = reason
            warnings.warn(f"{self.label}: {reason}", stacklevel=4)
        plans = self._plans_for["header" if chosen == "order" else chosen]
        dropped = dict(self._dropped_for["header" if chosen == "order" else chosen])
        if self._limit is not None and len(plans) > self._limit:
            dropped["beyond_limit"] = len(plans) - self._limit
            plans = plans[: self._limit]
        self._frames = plans
        self._resolve(plans, chosen)
        self.meta["dropped"] = dropped
        self.meta["frames_without_pose"] = sum(1 for p in plans if p.pose is None)
        if not plans:
            raise DataFormatError(f"{self.label}: no frames ({self._why_none(dropped)})")

    def _why_none(self, dropped: dict[str, int]) -> str:
        if self.kind == "rgbd":
            return (f"no colour and depth messages within {self.max_time_difference} s of each "
                    f"other: {dropped.get('depth_without_rgb', 0)} depth images unmatched")
        return "no clouds"

    def _setup_tf(self, world_frame, sensor, sensor_frame) -> None:
        tf = self._tf
        option = "sensor_frame" if sensor_frame else "the header frame_id"
        if sensor not in tf.frames():
            raise DataFormatError(
                f"{self.label}: sensor frame {sensor!r} ({option}) is not in /tf or /tf_static "
                f"(frames: {', '.join(sorted(tf.frames())) or 'none'})")
        world = _frame_name(world_frame) if world_frame else tf.root(sensor)
        if world not in tf.frames():
            raise DataFormatError(
                f"{self.label}: world frame {world!r} is not in /tf or /tf_static (frames: "
                f"{', '.join(sorted(tf.frames()))})")
        if tf.chain(world, sensor) is None:
            raise DataFormatError(
                f"{self.label}: no transform chain from {world} to {sensor} in /tf + "
                f"/tf_static ({sensor}'s root is {tf.root(sensor)})")
        self._world, self._sensor = world, sensor
        self.meta["world_frame"] = world
        self.meta["pose_source"] = f"tf {world} -> {sensor}: {tf.describe(world, sensor)}"
        self._pose_mode = "tf"

    def _setup_odom(self, pose_topic, sensor, sensor_frame, offset) -> None:
        samples = self._pose_samples
        if samples is None:
            raise DataFormatError(f"{self.label}: topic {pose_topic} has no messages")
        self._pose_mode = "odom"
        self.meta["world_frame"] = samples.parent
        child = samples.child
        desc = f"{self._type_of(pose_topic).split('/')[-1]} {pose_topic} " \
               f"({samples.parent or '?'} -> {child or '?'})"
        self._offset_static: np.ndarray | None = None
        self._offset_chain: tuple[str, str] | None = None
        if offset is not None:
            self._offset_static = offset
            note = "given (sensor_offset)"
        elif child and child == sensor:
            self._offset_static = np.eye(4)
            note = f"identity ({pose_topic} gives {sensor} itself)"
        elif child and sensor and self._tf.chain(child, sensor) is not None:
            self._offset_chain = (child, sensor)
            note = f"{child} -> {sensor} from /tf: {self._tf.describe(child, sensor)}"
        else:
            self._offset_static = np.eye(4)
            why = f"child_frame_id of {pose_topic} is empty" if not child else \
                f"no transform from {child} to {sensor} in /tf_static or /tf"
            note = f"identity ({why})"
            if child and sensor:
                warnings.warn(f"{self.label}: {note}; poses are those of {child}", stacklevel=5)
        self.meta["sensor_offset"] = note
        self.meta["pose_source"] = f"{desc}, sensor offset {note}"

    def _choose_time_source(self, requested: str, use_tf: bool) -> tuple[str, str]:
        if requested == "order" and use_tf:
            raise EvsmapError("time_source='order' needs a pose topic (odom_topic), not /tf")
        if requested != "auto":
            if requested == "order":
                self._check_order()
            return requested, ""
        header_plans = self._plans_for["header"]
        stamps_zero = all(m.stamp == 0 for p in header_plans for m in p.msgs)
        if not stamps_zero and self._covered(header_plans, "header"):
            return "header", ""
        spans = self._spans()
        if self._covered(self._plans_for["bag"], "bag"):
            why = "frame header stamps are all zero" if stamps_zero else \
                f"frame and pose header stamps do not overlap ({spans})"
            return "bag", f"{why}: frames and poses matched by bag (recording) time"
        if not use_tf and self._pose_samples is not None and \
                len(self._pose_samples.times) == len(header_plans):
            return "order", (f"frame and pose stamps do not overlap in header or bag time "
                             f"({spans}): the k-th frame takes the k-th pose message "
                             f"({len(header_plans)} of each)")
        raise DataFormatError(
            f"{self.label}: frame and pose times do not overlap ({spans}); pass "
            f"time_source='order' (k-th frame with the k-th pose message) or another pose "
            f"source")

    def _check_order(self) -> None:
        n_pose = len(self._pose_samples.times) if self._pose_samples else 0
        n_frames = len(self._plans_for["header"])
        if n_pose < min(n_frames, self._limit or n_frames):
            raise DataFormatError(f"{self.label}: time_source='order' needs a pose message per "
                                  f"frame: {n_frames} frames, {n_pose} pose messages")

    def _spans(self) -> str:
        def span(values: list[int]) -> str:
            return f"{_fmt(min(values))} .. {_fmt(max(values))}" if values else "none"

        frames = [p.time for p in self._plans_for["header"]]
        if self._pose_mode == "odom":
            assert self._pose_samples is not None  # odom mode: the pose topic's samples
            poses = list(self._pose_samples.times)
        else:
            poses = [t for c in self._tf.dynamic_links(self._world, self._sensor)
                     for t in self._tf.dynamic[c].times]
        return f"frames {span(frames)}, poses {span(poses)}"

    def _covered(self, plans: list[_Plan], source: str) -> bool:
        """Whether some frame has a pose under ``source``."""
        self._set_source(source)
        for plan in plans:
            try:
                self._pose_at(plan)
            except _NoPose:
                continue
            return True
        return not plans

    def _set_source(self, source: str) -> None:
        self._tf.set_source("bag" if source == "bag" else "header")
        if self._pose_samples is not None:
            self._track = self._pose_samples.track("bag" if source == "bag" else "header")

    def _pose_at(self, plan: _Plan, index: int | None = None) -> np.ndarray:
        gap = self.max_pose_gap
        if self._pose_mode == "tf":
            sensor = self._sensor_of(plan)
            pose = self._tf.lookup(self._world, sensor, plan.time, gap)
        else:
            if index is not None:  # time_source "order": the index-th message, as recorded
                samples = self._pose_samples  # (the track merges messages sharing a stamp)
                assert samples is not None
                pose = pose_matrix(np.asarray(samples.trans[index]),
                                   np.asarray(samples.quats[index]))
            else:
                pose = self._track.at(plan.time, gap)
            if self._offset_chain is not None:
                child, sensor = self._offset_chain
                pose = pose @ self._tf.lookup(child, sensor, plan.time, gap)
            else:
                pose = pose @ self._offset_static
        if self.kind == "rgbd" and self.camera_axes == "body":
            pose = pose @ BODY_TO_OPTICAL
        return pose

    def _sensor_of(self, plan: _Plan) -> str:
        """The frame's sensor frame: ``sensor_frame``, else its (colour or cloud) header's."""
        sensor = self.meta["sensor_frame"]
        frame = plan.msgs[0].frame_id
        if self._sensor_given or frame == sensor or not frame:
            return sensor
        if frame in self._tf.frames() and self._tf.chain(self._world, frame) is not None:
            return frame
        return sensor

    def _resolve(self, plans: list[_Plan], source: str) -> None:
        self._set_source(source)
        for k, plan in enumerate(plans):
            try:
                pose = self._pose_at(plan, k if source == "order" else None)
            except _NoPose as exc:
                plan.no_pose = str(exc)
                continue
            plan.pose = pose
