"""A smooth hand-held-like camera path that looks around a room.

The camera circles the room centre on an ellipse that keeps about 1.3 m from the walls (furniture
stands against them), at eye height with a slow bob, and looks across the room: the gaze points
inwards and sweeps +-50 deg around that direction, so one lap sees every wall and the furniture in
front of it from 2-5 m; pitch swings gently between floor-heavy and level views. Positions and
angles are smooth closed-form functions of time, so any frame can be rendered independently.
"""

from __future__ import annotations

import numpy as np

from evsmap.geometry import look_at, matrix_to_quat


def room_trajectory(
    room_size: tuple[float, float, float], num_frames: int, *, seed: int = 0, turns: float = 1.0,
    speed: float = 0.5, inset: float = 1.3, eye_height: float = 1.45, pitch: float = -0.32,
    laps: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera path through a room.

    Args:
        room_size: interior (length, width, height) in metres.
        num_frames: number of poses.
        seed: varies the phase, direction and wobble of the path.
        turns: scales the gaze sweep rate: 2 x ``turns`` side-to-side sweeps per lap.
        speed: walking speed in m/s that sets the timestamps (one lap per sequence, so longer
            sequences are denser in time, not longer in space).
        inset: distance in metres of the path from the walls (the ellipse's half-axes are the
            room's half-size minus ``inset``, at least 0.25 m).
        eye_height: mean camera height in metres (bobbing +-0.08 m, at most 0.5 m below the
            ceiling).
        pitch: mean pitch in radians (negative looks down); it swings +-0.18 rad about it.
        laps: times the path goes round the room (a robot's long run revisiting the same
            space); with more than one, the ellipse shrinks by up to 30 % towards the middle
            laps and the gaze sweeps differently on each, so a revisit sees the room from
            other poses. One lap is the path of earlier versions, bit for bit.

    Returns:
        timestamps (N,), translations (N, 3) and quaternions (N, 4, x y z w) of camera-to-world
        poses with OpenCV camera axes.
    """
    L, W, H = room_size
    rng = np.random.default_rng([seed, 7])
    phase = rng.uniform(0, 2 * np.pi)
    direction = rng.choice([-1.0, 1.0])
    wobble = rng.uniform(0, 2 * np.pi, 4)
    laps = int(laps)
    s = (np.linspace(0.0, float(laps), num_frames, endpoint=False) if num_frames > 1
         else np.zeros(1))
    angle = phase + direction * 2 * np.pi * s
    rx, ry = max(L / 2 - inset, 0.25), max(W / 2 - inset, 0.25)
    shrink = 1.0 - 0.3 * np.sin(np.pi * s / laps) if laps > 1 else 1.0
    eye = np.stack([
        L / 2 + rx * shrink * np.cos(angle),
        W / 2 + ry * shrink * np.sin(angle),
        np.minimum(eye_height + 0.08 * np.sin(2 * np.pi * 3 * s + wobble[0]), H - 0.5),
    ], axis=1)
    sweep = 2 * turns * (s if laps == 1 else s * (1.0 + 0.15 * np.floor(s) / laps))
    yaw = angle + np.pi + 0.85 * np.sin(2 * np.pi * sweep + wobble[1])
    tilt = pitch + 0.18 * np.sin(2 * np.pi * 1.5 * s + wobble[2])
    forward = np.stack([np.cos(yaw) * np.cos(tilt), np.sin(yaw) * np.cos(tilt), np.sin(tilt)], 1)
    rot = np.stack([look_at(e, e + f) for e, f in zip(eye, forward, strict=True)])
    quats = matrix_to_quat(rot)
    # time from arc length at the walking speed; values survive a "%.6f" text round trip
    steps = np.linalg.norm(np.diff(eye, axis=0), axis=1)
    elapsed = np.concatenate([[0.0], np.cumsum(steps)]) / speed
    stamps = np.array([float(f"{1.0 + t:.6f}") for t in elapsed])
    return stamps, eye, quats
