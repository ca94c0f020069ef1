"""
Handheld camera paths: pan, walk toward the target, orbit it, a fast pan, step back.

The path is a continuous function of time (motion blur needs poses inside the exposure). Each
leg eases in and out (minimum-jerk), so the walker stops between legs. Hand shake is a sum of
sinusoids: rotation all the time, translation (tremor, walking bob) only outside pure-rotation
legs, where the camera centre is exactly constant.
"""
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from absscale_ros.sim.scene import FloatArray, Scene

# Leg boundaries as fractions of the video: pan, approach, orbit, fast pan, step back.
_LEGS = (0.0, 0.12, 0.45, 0.74, 0.84, 1.0)
_ROTATION_LEGS = (0, 3)
_RAMP_S = 0.3  # translation shake fades in/out over this time next to pure rotations


@dataclass(frozen=True)
class _Sines:
    """Sum of sinusoids per axis: (k, 3) amplitudes, frequencies (Hz) and phases."""

    amp: FloatArray
    freq_hz: FloatArray
    phase: FloatArray

    def __call__(self, t_s: float) -> FloatArray:
        return np.sum(self.amp * np.sin(2.0 * np.pi * self.freq_hz * t_s + self.phase), axis=0)


def _sines(rng: np.random.Generator, amp: float, f_lo: float, f_hi: float, k: int = 3) -> _Sines:
    return _Sines(rng.uniform(0.3, 1.0, (k, 3)) * amp / k * 2.0,
                  rng.uniform(f_lo, f_hi, (k, 3)), rng.uniform(0.0, 2.0 * np.pi, (k, 3)))


def _ease(u: float) -> float:
    """Minimum-jerk profile 0 -> 1 with zero velocity and acceleration at both ends."""
    u = min(max(u, 0.0), 1.0)
    return u * u * u * (10.0 + u * (-15.0 + 6.0 * u))


@dataclass(frozen=True)
class Trajectory:
    """A handheld path; ``pose(t)`` is T_world_cam (4x4, m) at time ``t`` seconds."""

    duration_s: float
    times_s: tuple[float, ...]  # leg boundaries
    target_m: FloatArray  # point the walker films
    positions_m: FloatArray  # (6, 3) camera centre at the leg boundaries
    yaw_offsets_rad: tuple[float, ...]  # look-away angle at the leg boundaries
    pan_peak_rad: float  # look-away angle in the middle of the fast pan
    aim: _Sines  # slow aiming wander (rad)
    shake_rot: _Sines  # hand tremor (rad)
    shake_pos: _Sines  # hand tremor (m)
    bob: _Sines  # walking bob and sway (m)
    orbit: tuple[float, float, float, float]  # azimuth and radius at the orbit's ends

    def _leg(self, t_s: float) -> tuple[int, float]:
        k = int(np.clip(np.searchsorted(self.times_s, t_s, side='right') - 1, 0, 4))
        t0, t1 = self.times_s[k], self.times_s[k + 1]
        return k, _ease((t_s - t0) / (t1 - t0))

    def centre(self, t_s: float) -> FloatArray:
        """Camera centre without shake at time ``t_s``."""
        k, s = self._leg(t_s)
        p0, p1 = self.positions_m[k], self.positions_m[k + 1]
        if k == 2:  # orbit: interpolate azimuth and radius around the target
            az = self.orbit[0] + s * (self.orbit[1] - self.orbit[0])
            r = self.orbit[2] + s * (self.orbit[3] - self.orbit[2])
            height = p0[2] + s * (p1[2] - p0[2])
            return np.array([self.target_m[0] + r * np.cos(az),
                             self.target_m[1] + r * np.sin(az), height])
        return p0 + s * (p1 - p0)

    def shake_weight(self, t_s: float) -> float:
        """0 inside pure-rotation legs, rising to 1 within ``_RAMP_S`` outside them."""
        gap = np.inf
        for k in _ROTATION_LEGS:
            t0, t1 = self.times_s[k], self.times_s[k + 1]
            gap = min(gap, max(t0 - t_s, t_s - t1, 0.0))
        return _ease(gap / _RAMP_S)

    def pose(self, t_s: float) -> FloatArray:
        """T_world_cam at ``t_s``: camera centre, look-at with aim wander, roll and tremor."""
        k, s = self._leg(t_s)
        w = self.shake_weight(t_s)
        speed = np.linalg.norm(self.centre(t_s + 0.05) - self.centre(t_s - 0.05)) / 0.1
        walking = min(speed / 0.8, 1.0)
        centre = self.centre(t_s) + w * (self.shake_pos(t_s) + walking * self.bob(t_s))
        if k == 3:  # fast pan: away and back
            yaw = self.pan_peak_rad * np.sin(np.pi * s)
        else:
            yaw = self.yaw_offsets_rad[k] + s * (self.yaw_offsets_rad[k + 1]
                                                 - self.yaw_offsets_rad[k])
        aim = self.aim(t_s)
        forward = self.target_m - self.centre(t_s)
        R = _look(forward, yaw + aim[0], aim[1], aim[2])
        R = R @ _small_rotation(self.shake_rot(t_s))
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = centre
        return T

    def rotation_frames(self, fps: float, count: int, margin_s: float = 0.02) -> list[list[int]]:
        """[first, last] frame indices of pure-rotation legs (exposure kept inside the leg)."""
        out = []
        for k in _ROTATION_LEGS:
            t0, t1 = self.times_s[k] + margin_s, self.times_s[k + 1] - margin_s
            frames = [i for i in range(count) if t0 <= i / fps <= t1]
            if frames:
                out.append([frames[0], frames[-1]])
        return out


def _look(forward: FloatArray, yaw: float, pitch: float, roll: float) -> FloatArray:
    """R_world_cam (optical frame) looking along ``forward`` turned by yaw / pitch, then roll."""
    f = forward / np.linalg.norm(forward)
    c, s = np.cos(yaw), np.sin(yaw)
    f = np.array([c * f[0] - s * f[1], s * f[0] + c * f[1], f[2]])
    horizontal = np.hypot(f[0], f[1])
    elevation = np.arctan2(f[2], horizontal) + pitch
    heading = np.arctan2(f[1], f[0])
    f = np.array([np.cos(elevation) * np.cos(heading), np.cos(elevation) * np.sin(heading),
                  np.sin(elevation)])
    right = np.cross(f, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(f, right)
    R = np.stack([right, down, f], axis=1)
    return R @ _small_rotation(np.array([0.0, 0.0, roll]))


def _small_rotation(angles_rad: FloatArray) -> FloatArray:
    """Rotation by a rotation vector (Rodrigues), camera axes."""
    theta = float(np.linalg.norm(angles_rad))
    if theta < 1e-15:
        return np.eye(3)
    k = np.asarray(angles_rad) / theta
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * K @ K


def make(scene: Scene, duration_s: float, rng: np.random.Generator) -> Trajectory:
    """
    Draw a path for ``scene`` (its ``walk`` hints) lasting ``duration_s``.

    Retries with a smaller orbit if the camera would pass through furniture or objects.
    """
    w = scene.walk
    target = np.array([w['target_x'], w['target_y'], w['target_z']])
    for attempt in range(20):
        traj = _draw(w, target, duration_s, rng, shrink=0.85 ** attempt)
        if _clear(traj, scene.obstacles):
            return traj
    return traj


def _draw(w: dict[str, float], target: FloatArray, duration_s: float,
          rng: np.random.Generator, shrink: float) -> Trajectory:
    times = tuple(f * duration_s for f in _LEGS)
    eye = w['eye_height_m']
    mid, near = w['mid_m'], w['near_m']
    far = min(w['far_m'], mid + w['max_speed_mps'] * (times[2] - times[1]))
    az0 = w['approach_rad']
    az1 = az0 + w['orbit_rad'] * shrink
    back = 0.5 * (mid + near) * rng.uniform(0.9, 1.2)

    def at(az: float, r: float, dh: float = 0.0) -> FloatArray:
        p = np.array([target[0] + r * np.cos(az), target[1] + r * np.sin(az),
                      eye + dh + rng.uniform(-0.05, 0.05)])
        p[0] = np.clip(p[0], w['room_x0'], w['room_x1'])
        p[1] = np.clip(p[1], w['room_y0'], w['room_y1'])
        return p

    start = at(az0 + rng.uniform(-0.15, 0.15), far)
    arrive = at(az0, mid)
    orbit_end = at(az1, near, dh=rng.uniform(-0.2, 0.05))
    retreat = at(az1 + 0.3 * (az1 - az0), back)
    positions = np.stack([start, start, arrive, orbit_end, orbit_end, retreat])
    yaw0 = np.deg2rad(rng.uniform(35.0, 55.0)) * rng.choice([-1.0, 1.0])
    r_arrive, r_end = (float(np.hypot(*(p[:2] - target[:2]))) for p in (arrive, orbit_end))
    az_arrive, az_end = (float(np.arctan2(*(p[1::-1] - target[1::-1])))
                         for p in (arrive, orbit_end))
    az_end = az_arrive + (az_end - az_arrive + np.pi) % (2.0 * np.pi) - np.pi
    return Trajectory(
        duration_s, times, target, positions, (yaw0, 0.0, 0.0, 0.0, 0.0, 0.0),
        np.deg2rad(rng.uniform(35.0, 50.0)) * rng.choice([-1.0, 1.0]),
        _sines(rng, np.deg2rad(4.0), 0.05, 0.2), _sines(rng, np.deg2rad(0.35), 1.0, 6.0),
        _sines(rng, 0.002, 2.0, 7.0),
        _Sines(np.array([[0.008, 0.008, 0.015]]), np.array([[0.9, 0.9, 1.8]]),
               rng.uniform(0.0, 2.0 * np.pi, (1, 3))),
        (az_arrive, az_end, r_arrive, r_end))


def _clear(traj: Trajectory, obstacles: list[FloatArray], margin_m: float = 0.25) -> bool:
    """True when no sampled camera centre comes within ``margin_m`` of an obstacle box."""
    for t in np.linspace(0.0, traj.duration_s, 200):
        p = traj.centre(t)
        for box in obstacles:
            if np.all(p >= box[0] - margin_m) and np.all(p <= box[1] + margin_m):
                return False
    return True


def positions(traj: Trajectory, times_s: npt.ArrayLike) -> FloatArray:
    """(N, 3) camera centres (with shake) at ``times_s``."""
    return np.array([traj.pose(float(t))[:3, 3] for t in np.asarray(times_s).ravel()])
