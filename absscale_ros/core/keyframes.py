"""
Keyframe selection: which frames of a handheld video are worth reconstructing.

After Rashidi et al. 2013 ("Optimized selection of key frames for monocular videogrammetric
surveying"): a blurred frame is never chosen (variance of the Laplacian against a running
median); corners detected in the last keyframe are tracked frame to frame (pyramidal KLT);
a frame becomes a keyframe when the tracked ratio falls or the baseline grows past thresholds,
provided two-view geometry shows real translation (GRIC, see ``keyframe_geometry``), so pure
rotations and tiny baselines never make keyframes. Frames in which the calibration target is
seen large enough are preferred. Tracking runs on a grey image downscaled to
``track_width_px``.

The baseline ratio is measured against the depths of all the keyframe's corners triangulated
so far, not only those still tracked: walking on, the near corners leave the view first, and
the survivors' median depth alone grows with the baseline (outdoors it underestimated the
ratio three times, and keyframes came past the band). Even so the estimate can fall behind
on a fast walk away from a deep scene, so the ratio is also predicted at constant speed: the
fastest growth per second measured since the reference (or the last turn or degenerate
frame: a pause), times the time since it.
"""
from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import keyframe_geometry
from absscale_ros.core.types import CameraModel

FloatArray = npt.NDArray[np.float64]
GRID = (4, 3)  # columns, rows of the corner detection grid


@dataclass(frozen=True)
class KeyframeConfig:
    """
    Thresholds of the keyframe selector (all are ROS parameters of ``keyframe_selector``).

    :param track_width_px: width of the grey image tracked on (height keeps the aspect).
    :param max_features: corners detected in each keyframe.
    :param min_feature_distance_px: spacing of those corners, at tracking scale.
    :param blur_window: frames in the running median of the sharpness score.
    :param min_sharpness_ratio: a frame whose Laplacian variance (on the tracking image
        reduced four times) is below this fraction of the running median is blurred.
    :param min_tracked_ratio: a keyframe is due when fewer than this fraction of the last
        keyframe's corners are still tracked.
    :param max_track_error: largest KLT residual (mean absolute grey-level difference over the
        window) of a corner still counted as tracked.
    :param lost_tracks: fewer tracked corners than this means tracking is lost.
    :param min_flow_px: median corner displacement (tracking scale) before the (costlier)
        two-view test runs.
    :param min_baseline_ratio: lower end of the baseline / median depth band of keyframe pairs.
    :param target_baseline_ratio: estimated baseline / depth at which a keyframe is taken.
    :param max_baseline_ratio: upper end of the band (reported; a late keyframe is still taken).
    :param no_target_factor: without the target in view, wait until the baseline ratio reaches
        ``target_baseline_ratio`` times this (or the tracks run low), to prefer target frames.
    :param min_target_area: target area / image area for a frame to count as showing it.
    :param min_parallax_px: median parallax left after removing the best pure rotation
        (tracking scale) below which the motion counts as degenerate.
    :param max_step_flow_px: frame-to-frame corner motion (tracking scale) above which a
        frame is never a keyframe (the camera swings too fast to trust the tracks).
    :param min_turn_flow_px: frame-to-frame corner motion (tracking scale) above which the
        camera may be turning on the spot, see next.
    :param min_step_parallax_fraction: a candidate whose frame-to-frame parallax left after
        the best pure rotation is below this fraction of its frame-to-frame motion is turning
        on the spot (inside a pure rotation every frame shares the centre of the frame that
        started it) and waits.
    :param turn_hold_frames: frames after a turn (or a too fast swing) before a keyframe:
        a pan that slows to reverse is still a pan.
    :param sigma_px: corner position noise at tracking scale, px (GRIC and RANSAC).
    :param min_inliers: two-view inliers needed to trust the geometry.
    """

    track_width_px: int = 640
    max_features: int = 150
    min_feature_distance_px: float = 12.0
    blur_window: int = 45
    min_sharpness_ratio: float = 0.6
    min_tracked_ratio: float = 0.5
    max_track_error: float = 20.0
    lost_tracks: int = 20
    min_flow_px: float = 6.0
    min_baseline_ratio: float = 0.03
    target_baseline_ratio: float = 0.08
    max_baseline_ratio: float = 0.3
    no_target_factor: float = 1.5
    min_target_area: float = 0.005
    min_parallax_px: float = 3.0
    max_step_flow_px: float = 40.0
    min_turn_flow_px: float = 3.0
    min_step_parallax_fraction: float = 0.1
    turn_hold_frames: int = 6
    sigma_px: float = 1.0
    min_inliers: int = 15

    def __post_init__(self) -> None:
        if self.track_width_px < 64 or self.max_features < 8 or self.blur_window < 1:
            raise ValueError('track_width_px >= 64, max_features >= 8, blur_window >= 1')
        if not 0.0 <= self.min_sharpness_ratio <= 1.0 or not 0.0 < self.min_tracked_ratio < 1.0:
            raise ValueError('min_sharpness_ratio in [0, 1], min_tracked_ratio in (0, 1)')
        if not 0.0 < self.min_baseline_ratio <= self.target_baseline_ratio \
                <= self.max_baseline_ratio:
            raise ValueError('need 0 < min_baseline_ratio <= target_baseline_ratio '
                             '<= max_baseline_ratio')
        if self.max_step_flow_px <= self.min_turn_flow_px:
            raise ValueError('max_step_flow_px must exceed min_turn_flow_px')
        if self.turn_hold_frames < 0:
            raise ValueError('turn_hold_frames must be >= 0')
        if self.lost_tracks < 5 or self.min_inliers < 5 or self.no_target_factor < 1.0:
            raise ValueError('lost_tracks >= 5, min_inliers >= 5, no_target_factor >= 1')
        if min(self.sigma_px, self.max_track_error) <= 0.0 or min(
                self.min_flow_px, self.min_parallax_px, self.min_turn_flow_px,
                self.min_step_parallax_fraction, self.min_target_area) < 0.0:
            raise ValueError('sigma_px, max_track_error > 0; min_flow_px, min_parallax_px, '
                             'min_turn_flow_px, min_target_area >= 0')


@dataclass(frozen=True)
class TrackedStep:
    """
    The camera's motion since the previous keyframe, measured by tracking corners frame to
    frame. Those steps are a few pixels, so a repeated texture cannot fool them the way it can
    fool matching two keyframes a texture period apart; the SfM checks its poses against it.

    :param ref_stamp_ns: stamp of the previous keyframe.
    :param rotation: (3, 3) R_this_ref.
    :param centre: (3,) this camera's centre in the previous keyframe's camera frame, in units
        of the median depth of the previous keyframe's corners (scale-free).
    """

    ref_stamp_ns: int
    rotation: FloatArray
    centre: FloatArray


def chain(first: TrackedStep, then: TrackedStep) -> TrackedStep:
    """
    The step over two tracked steps (``then`` starts where ``first`` ends), for a keyframe
    whose previous one never made it into the map. Each centre is in units of its own
    reference's depth: taken as equal, which matters to the length, hardly to the direction.
    """
    return TrackedStep(first.ref_stamp_ns, then.rotation @ first.rotation,
                       first.centre + first.rotation.T @ then.centre)


@dataclass(frozen=True)
class Decision:
    """
    What the selector made of one frame.

    :param reason: why it is or is not a keyframe: 'first', 'baseline', 'tracks', 'blurred',
        'degenerate', 'rotating', 'fast', 'lost', 'waiting', 'undetected' (would be one, but
        the detector skipped it).
    :param sharpness_ratio: Laplacian variance / running median (1.0 = typical).
    :param tracked_ratio: corners still tracked / corners detected in the reference.
    :param baseline_ratio: estimated baseline / median depth to the last keyframe, or its
        constant-speed prediction when larger (NaN if the two-view test did not run or was
        degenerate).
    :param after_loss: for a keyframe: tracking to the previous keyframe was lost in between,
        so the pair shares no tracked corners.
    :param step: for a keyframe: its tracked motion from the previous keyframe (None for the
        first, after a loss, or when the two-view test did not measure one).
    """

    stamp_ns: int
    keyframe: bool
    reason: str
    sharpness_ratio: float
    tracked_ratio: float
    baseline_ratio: float
    target_area: float
    after_loss: bool = False
    step: TrackedStep | None = None


@dataclass(frozen=True, eq=False)
class Measured:
    """
    A frame the selector tracked and measured, not yet decided on (``KeyframeSelector.measure``).

    :param reason: the decision's reason when the target cannot change it ('first', or a
        non-keyframe's), '' when the baseline decides.
    :param baseline_ratio: the baseline ratio the decision uses (NaN as in ``Decision``).
    :param low_tracks: fewer than ``min_tracked_ratio`` of the reference's corners tracked.
    :param grey: the tracking image (a keyframe's corners are detected in it).
    """

    stamp_ns: int
    reason: str
    sharpness_ratio: float
    tracked_ratio: float
    baseline_ratio: float
    low_tracks: bool
    grey: npt.NDArray[np.uint8]


class KeyframeSelector:
    """Stateful selector: call ``update`` once per frame, in stamp order."""

    def __init__(self, cfg: KeyframeConfig) -> None:
        self.cfg = cfg
        self._scores: deque[float] = deque(maxlen=cfg.blur_window)
        self._prev: npt.NDArray[np.uint8] | None = None
        self._pts: npt.NDArray[np.float32] | None = None  # (N, 1, 2) tracked now
        self._pts0: npt.NDArray[np.float32] | None = None  # the same corners in the reference
        self._ids = np.zeros(0, np.int64)  # index in the reference of each tracked corner
        self._depths = np.zeros(0)  # (seeded,) reference depths, common unit (NaN: unknown)
        self._stamp_ns = 0  # of the frame being decided
        self._ref_stamp_ns = 0  # of the reference the corners were detected in
        self._rate_per_ns = 0.0  # fastest growth of the baseline ratio since the reference
        self._cams: tuple[CameraModel, CameraModel] | None = None
        self._last_step: npt.NDArray[np.float32] | None = None
        self._seeded = 0
        self._in_loss = False
        self._since_turn = 1 << 30  # frames since the camera last turned on the spot
        self._have_keyframe = False
        self._lost_since_keyframe = False
        self._measured: TrackedStep | None = None  # this frame's motion from the reference
        self.lost_count = 0

    def _grey(self, image_bgr: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
        h, w = image_bgr.shape[:2]
        grey = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY) if image_bgr.ndim == 3 else image_bgr
        if w > self.cfg.track_width_px:
            size = (self.cfg.track_width_px, max(1, round(h * self.cfg.track_width_px / w)))
            grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
        return grey

    def _track_camera(self, camera: CameraModel, grey: npt.NDArray[np.uint8]) -> CameraModel:
        if self._cams is None or self._cams[0] is not camera:
            self._cams = (camera, camera.resized(grey.shape[1], grey.shape[0]))
        return self._cams[1]

    def _sharpness_ratio(self, grey: npt.NDArray[np.uint8]) -> float:
        # On a quarter-size image: sensor noise, added after the blur, would otherwise keep
        # the Laplacian variance of a smeared frame high.
        score = keyframe_geometry.sharpness(cv2.pyrDown(cv2.pyrDown(grey)))
        median = float(np.median(self._scores)) if len(self._scores) >= 3 else 0.0
        ratio = score / median if median > 0.0 else 1.0
        self._scores.append(score)
        return ratio if np.isfinite(ratio) else 1.0

    def _seed(self, grey: npt.NDArray[np.uint8]) -> None:
        # Corners per cell of a 4 x 3 grid, so that the tracks (and the median depth the
        # baseline is measured against) cover the whole view, not only its busiest texture.
        h, w = grey.shape
        per_cell = max(1, self.cfg.max_features // (GRID[0] * GRID[1]))
        found = []
        for i in range(GRID[0]):
            for j in range(GRID[1]):
                x0, x1 = i * w // GRID[0], (i + 1) * w // GRID[0]
                y0, y1 = j * h // GRID[1], (j + 1) * h // GRID[1]
                pts = cv2.goodFeaturesToTrack(grey[y0:y1, x0:x1], per_cell, 0.01,
                                              self.cfg.min_feature_distance_px, blockSize=5)
                if pts is not None:
                    found.append(pts + np.array([x0, y0], np.float32))
        self._pts = np.concatenate(found) if found else np.zeros((0, 1, 2), np.float32)
        self._pts0 = self._pts.copy()
        self._seeded = len(self._pts)
        self._ids = np.arange(self._seeded)
        self._depths = np.full(self._seeded, np.nan)
        self._ref_stamp_ns, self._rate_per_ns = self._stamp_ns, 0.0

    def _track(self, grey: npt.NDArray[np.uint8]) -> None:
        if self._prev is None or self._pts is None or self._pts0 is None or not len(self._pts):
            return
        nxt, status, err = cv2.calcOpticalFlowPyrLK(self._prev, grey, self._pts, None,
                                                    winSize=(15, 15), maxLevel=3)
        h, w = grey.shape
        ok = status.ravel().astype(bool) & np.all(np.isfinite(nxt.reshape(-1, 2)), axis=1) \
            & (err.ravel() <= self.cfg.max_track_error)
        xy = nxt.reshape(-1, 2)
        ok &= (xy[:, 0] >= 0) & (xy[:, 0] <= w - 1) & (xy[:, 1] >= 0) & (xy[:, 1] <= h - 1)
        self._last_step = self._pts[ok]  # where the surviving corners were one frame ago
        self._pts, self._pts0, self._ids = nxt[ok], self._pts0[ok], self._ids[ok]

    def _geometry(self, cam: CameraModel) -> keyframe_geometry.Motion | None:
        """Two-view test against the reference; None when a pure rotation already explains
        the tracks (a cheap fit that spares the essential-matrix RANSAC)."""
        assert self._pts is not None and self._pts0 is not None
        xy0 = cv2.undistortPoints(self._pts0, cam.K, cam.dist).reshape(-1, 2).astype(np.float64)
        xy1 = cv2.undistortPoints(self._pts, cam.K, cam.dist).reshape(-1, 2).astype(np.float64)
        f_px = float(cam.K[0, 0])
        _, rot_sq = keyframe_geometry.rotation_fit(xy0, xy1)
        if np.sqrt(np.median(rot_sq)) * f_px < self.cfg.min_parallax_px:
            return None
        return keyframe_geometry.analyse(xy0, xy1, self.cfg.sigma_px / f_px,
                                         self.cfg.min_inliers, self.cfg.min_parallax_px / f_px,
                                         rot_sq=rot_sq)

    def update(self, stamp_ns: int, image_bgr: npt.NDArray[np.uint8], camera: CameraModel,
               target_area: float = 0.0, detected: bool = True) -> Decision:
        """
        Decide whether the frame is a keyframe (``measure`` then ``decide``).

        :param image_bgr: (H, W, 3) uint8 BGR (or (H, W) grey) image of ``camera``.
        :param camera: intrinsics of this image (distortion allowed).
        :param target_area: largest calibration target's area / image area (0 if none seen).
        :param detected: whether the target detector looked at this frame. Live, a detector
            that is behind skips frames; a keyframe without its vertices cannot add the target
            to the map, so such a frame is passed over ('undetected') for the next detected one
            unless tracking is running out or the baseline has reached its maximum.
        """
        return self.decide(self.measure(stamp_ns, image_bgr, camera), target_area, detected)

    def measure(self, stamp_ns: int, image_bgr: npt.NDArray[np.uint8],
                camera: CameraModel) -> Measured:
        """
        Track the frame and measure it against the reference: everything ``update`` does that
        does not depend on the target. ``decide`` must follow before the next frame is measured.
        """
        self._stamp_ns, self._measured = stamp_ns, None
        grey = self._grey(image_bgr)
        cam = self._track_camera(camera, grey)
        sharp = self._sharpness_ratio(grey)
        self._track(grey)
        self._prev = grey
        blurred = sharp < self.cfg.min_sharpness_ratio
        n = len(self._pts) if self._pts is not None else 0
        tracked = n / self._seeded if self._seeded else 0.0

        def measured(reason: str, ratio: float = float('nan'), low_tracks: bool = False
                     ) -> Measured:
            return Measured(stamp_ns, reason, sharp, tracked, ratio, low_tracks, grey)

        turning = self._turning(cam) if n >= self.cfg.lost_tracks else ''
        self._since_turn = 0 if turning else self._since_turn + 1
        if turning:
            self._rate_per_ns = 0.0  # the walk paused: its speed so far predicts nothing
        if not self._have_keyframe and not blurred:
            return measured('first')
        if n < self.cfg.lost_tracks:
            return measured(self._lost(grey, blurred))
        self._in_loss = False
        if blurred:
            return measured('blurred')
        assert self._pts is not None and self._pts0 is not None
        flow_px = float(np.median(np.linalg.norm((self._pts - self._pts0).reshape(-1, 2), axis=1)))
        low_tracks = tracked < self.cfg.min_tracked_ratio
        if flow_px < self.cfg.min_flow_px and not low_tracks:
            return measured('waiting')
        if turning or self._since_turn < self.cfg.turn_hold_frames:
            return measured(self._lost(grey, False) if low_tracks else turning or 'rotating')
        geo = self._geometry(cam)
        if geo is None or geo.degenerate:
            self._rate_per_ns = 0.0
            # Few corners left and still no baseline: the overlap with the last keyframe is
            # going; start again from here rather than wait on a handful of far corners.
            return measured(self._lost(grey, False) if low_tracks else 'degenerate')
        ratio = self._pooled_ratio(geo)
        if np.isfinite(ratio) and geo.rotation is not None and geo.direction is not None:
            self._measured = TrackedStep(self._ref_stamp_ns, geo.rotation,
                                         -geo.rotation.T @ geo.direction * ratio)
        return measured('', self._predicted_ratio(ratio), low_tracks)

    def needs_target(self, m: Measured) -> bool:
        """
        Whether ``decide`` on ``m`` wants the target's area: the frame is a keyframe if the
        target is in view (whose vertices go out with it). Every other frame is decided the
        same without it (``no_target_factor`` >= 1: no frame becomes a keyframe sooner without
        the target), so a detector asked only for these frames gives the same keyframes.
        """
        return m.reason == 'first' or (m.reason == '' and self._by_baseline(m, True)[0])

    def decide(self, m: Measured, target_area: float = 0.0, detected: bool = True) -> Decision:
        """Decide on the frame ``measure`` just measured (see ``update`` for the arguments)."""
        keyframe, reason = (m.reason == 'first', m.reason) if m.reason else \
            self._by_baseline(m, target_area >= self.cfg.min_target_area)
        ratio = m.baseline_ratio
        if keyframe and not detected and reason in ('first', 'baseline') \
                and not ratio >= self.cfg.max_baseline_ratio:
            keyframe, reason = False, 'undetected'
        after_loss = keyframe and self._lost_since_keyframe
        step = self._measured if keyframe and not after_loss else None
        if keyframe:
            self._seed(m.grey)
            self._have_keyframe, self._lost_since_keyframe = True, False
        return Decision(m.stamp_ns, keyframe, reason, m.sharpness_ratio, m.tracked_ratio, ratio,
                        target_area, after_loss, step)

    def _pooled_ratio(self, geo: keyframe_geometry.Motion) -> float:
        """
        Baseline / median depth of every reference corner triangulated so far.

        ``geo.depths`` are in units of this frame's baseline; the corners also in the pool
        give that baseline in the pool's unit (median of the depth ratios), then the fresh
        depths replace the pool's (a longer baseline measures them better). Corners lost
        since keep their last depth.
        """
        if geo.depths is None:
            return geo.baseline_ratio
        fresh = np.isfinite(geo.depths)
        known = self._depths[self._ids]
        both = fresh & np.isfinite(known)
        if np.count_nonzero(both) >= 5:
            baseline = float(np.median(known[both] / geo.depths[both]))
        else:  # nothing to relate to: this frame's baseline starts the pool's unit
            self._depths[:] = np.nan
            baseline = 1.0
        self._depths[self._ids[fresh]] = baseline * geo.depths[fresh]
        return baseline / float(np.nanmedian(self._depths))

    def _turning(self, cam: CameraModel) -> str:
        """'fast' or 'rotating' when the camera swings, or turns on the spot; else ''."""
        if self._last_step is None or self._pts is None or len(self._pts) < 5:
            return ''
        flow_px = float(np.median(np.linalg.norm((self._pts - self._last_step).reshape(-1, 2),
                                                 axis=1)))
        if flow_px > self.cfg.max_step_flow_px:
            return 'fast'  # a whip pan: smeared corners, unreliable tracks
        if flow_px < self.cfg.min_turn_flow_px:
            return ''
        parallax_px, _ = self._step_parallax_px(cam)
        return 'rotating' if parallax_px < self.cfg.min_step_parallax_fraction * flow_px else ''

    def _step_parallax_px(self, cam: CameraModel) -> tuple[float, float]:
        """
        Parallax between the previous frame and this one that no rotation explains, and the
        median corner motion between them, px at tracking scale.

        Inside a pure rotation every frame sits at the centre of the frame that started it, so
        it may pass the baseline test against the last keyframe; it must still not become a
        keyframe: the one that started the rotation already holds that viewpoint.
        """
        if self._last_step is None or self._pts is None or len(self._pts) < 5:
            return float('inf'), 0.0
        xy0 = cv2.undistortPoints(self._last_step, cam.K, cam.dist).reshape(-1, 2)
        xy1 = cv2.undistortPoints(self._pts, cam.K, cam.dist).reshape(-1, 2)
        _, res_sq = keyframe_geometry.rotation_fit(xy0.astype(np.float64),
                                                   xy1.astype(np.float64))
        flow_px = np.linalg.norm((self._pts - self._last_step).reshape(-1, 2), axis=1)
        return float(np.sqrt(np.median(res_sq))) * float(cam.K[0, 0]), float(np.median(flow_px))

    def _lost(self, grey: npt.NDArray[np.uint8], blurred: bool) -> str:
        """Tracking is lost: restart tracking here, without a keyframe (no baseline to check)."""
        if not self._in_loss:
            self.lost_count += 1  # count each loss once, not every frame of it
            self._in_loss = True
        self._lost_since_keyframe = True
        if not blurred:
            self._seed(grey)  # a provisional reference: the next keyframe is measured from it
        return 'lost'

    def _predicted_ratio(self, ratio: float) -> float:
        """
        The measured ratio, or its constant-speed prediction when larger; only once the
        measured ratio is in the band, so a camera that stopped is not taken for one still
        walking.
        """
        dt_ns = self._stamp_ns - self._ref_stamp_ns
        if np.isfinite(ratio) and dt_ns > 0 and ratio >= self.cfg.min_baseline_ratio:
            self._rate_per_ns = max(self._rate_per_ns, ratio / dt_ns)
            ratio = max(ratio, self._rate_per_ns * dt_ns)
        return ratio

    def _by_baseline(self, m: Measured, has_target: bool) -> tuple[bool, str]:
        cfg = self.cfg
        ratio = m.baseline_ratio
        wanted = cfg.target_baseline_ratio * (1.0 if has_target else cfg.no_target_factor)
        if ratio >= min(wanted, cfg.max_baseline_ratio):
            return True, 'baseline'
        if m.low_tracks and ratio >= cfg.min_baseline_ratio:
            return True, 'tracks'
        return False, 'waiting'
