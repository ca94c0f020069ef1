"""
Incremental dense cloud: keyframe depth maps checked against their neighbours, fused by voxel.

Each keyframe gets one depth map (``dense_stereo``) from the best partner among its
neighbours. A depth pixel survives when the depth maps of at least ``min_consistent`` other
keyframes see the same surface within ``consistency_rel`` of its depth (multi-view
consistency: stereo mistakes rarely repeat in another pair). The survivors of each keyframe are
voxel-downsampled, cleared of statistical outliers and given normals once, and cached in the
keyframe's camera frame; the cloud is the voxel average of those caches placed by the latest
poses. A new keyframe costs its depth maps and the check of its own points; an old keyframe's
cache is rebuilt only when one of its depth maps is recomputed because its pair moved
materially, rescaled when only the scale changed, and otherwise just moved with its pose.
A keyframe also gets a plane-sweep depth map over its neighbours (``dense_sweep``, at a lower
resolution), which covers what its pairs cannot: where the camera moved along its view. Its
points are kept where no pair of the keyframe has depth, and it votes for the pairs' points.
Optionally (``dense_facade``) far planes fitted to a wide-baseline sweep fill what is left,
(``dense_fill``) plain holes get the plane of the points around them, and (``dense_ground``)
the ground beyond stereo's reach gets the near ground's plane.
"""
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any, Callable

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import dense_cloud, dense_facade, dense_fill, dense_ground, dense_stereo, \
    dense_sweep
from absscale_ros.core.types import CameraModel

FloatArray = npt.NDArray[np.float64]
_NEW = -1.0  # a depth map was (re)computed, as opposed to a rescale factor
SWEEP = 2  # key of the plane-sweep depth map among a keyframe's depth maps (pairs: +-1, 0)
FACADE = 3  # key of the far planes' depth map (``dense_facade``)


@dataclass(frozen=True)
class FusionConfig:
    """Consistency, pose-change and cloud-cleaning thresholds."""

    voxel_m: float = 0.01  # voxel edge of the fused cloud, m
    consistency_rel: float = 0.005  # depths agreeing within this fraction are the same surface
    min_consistent: int = 1  # other keyframes' depth maps that must agree
    sweep_consistent: int = 1  # ... with a point only the plane sweep found (noisier)
    facade_consistent: int = 1  # ... with a point only a far plane gave (``dense_facade``)
    facade_rel: float = 0.002  # ... agreeing within this fraction of its depth
    facade_revote: bool = True  # a keyframe's new far points re-check its earlier neighbours'
    neighbours: int = 3  # keyframes on each side a depth pixel is checked against
    max_new_maps: int = 2  # stereo pairs computed per update at most (the rest wait)
    both_sides: bool = True  # a partner on each side of a keyframe (two depth maps), else one
    recompute_deg: float = 0.2  # pair rotation / baseline direction moved more: new depth
    average: bool = True  # a kept point is the mean of the depth maps that agree with it
    sweep_average: bool = False  # ... the sweeps' included for a pair's point (else they vote)
    outlier_neighbours: int = 16  # statistical outlier removal: neighbours considered
    outlier_std: float = 2.0  # ... and the mean-distance threshold, in standard deviations
    # (0: no statistical removal)
    normal_neighbours: int = 20  # points used for a normal
    move_voxels: float = 0.25  # a keyframe whose new pose moves its points less stays fused
    threads: int = 2  # keyframe clouds of one update built at once (the same clouds)


@dataclass
class _Keyframe:
    image: np.ndarray  # at the working scale
    camera: CameraModel
    pose: FloatArray | None = None  # T_world_cam, metres
    depths: dict[int, dense_stereo.DepthMap] = field(default_factory=dict)  # by side, +1 / -1
    cloud: Any = None  # cached open3d cloud in the camera frame (None: to be rebuilt)
    view: Any = None  # (bgr, grey, K) undistorted at the sweep's scale, made when first swept
    swept_with: dict[int, FloatArray] = field(default_factory=dict)  # neighbour -> T_nb_kf
    placed: FloatArray | None = None  # the pose its cloud is in the fused voxels with
    reach: float = 0.0  # farthest point of its cloud from the camera, m
    fine: Any = None  # (uint8 grey, K) at full size, undistorted (far planes' refinement)
    facade_with: dict[int, FloatArray] = field(default_factory=dict)  # far view -> T_nb_kf
    planes: list[tuple[FloatArray, int]] = field(default_factory=list)  # far planes p (p.X = 1
    # in its camera) and the pixels that refined each
    filled: bool = False  # its cloud holds the plane fill of its plain holes (``dense_fill``)
    # and of its ground (``dense_ground``)


def _measured(kf: _Keyframe) -> list[dense_stereo.DepthMap]:
    """The keyframe's depth maps measured from image matches: its pairs and its sweep, not
    the far planes filled from them (``FACADE``), which must not feed back."""
    return [m for side, m in kf.depths.items() if side != FACADE]


def _pixels_hit(points: list[FloatArray], K: FloatArray,
                shape: tuple[int, ...]) -> npt.NDArray[np.bool_]:
    """Pixels of a (h, w) pinhole view (K) that camera-frame ``points`` fall on, dilated by
    one pixel (the gaps between projected points)."""
    h, w = shape
    hit = np.zeros((h, w), np.uint8)
    for pts in points:
        p = dense_stereo.transform(pts, K)
        u = np.rint(p[:, 0] / p[:, 2]).astype(np.intp)
        v = np.rint(p[:, 1] / p[:, 2]).astype(np.intp)
        ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        hit[v[ok], u[ok]] = 1
    return cv2.dilate(hit, np.ones((3, 3), np.uint8)) > 0


def _angle_deg(a: FloatArray, b: FloatArray) -> float:
    cos = np.dot(a, b) / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12)
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def _rotation_deg(R: FloatArray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


class DenseFusion:
    """Keyframes in, a metric dense cloud out; call ``update`` whenever poses arrive."""

    def __init__(self, stereo: dense_stereo.StereoConfig, fusion: FusionConfig,
                 sweep: dense_sweep.SweepConfig | None = None,
                 facade: dense_facade.FacadeConfig | None = None,
                 fill: dense_fill.FillConfig | None = None,
                 ground: dense_ground.GroundConfig | None = None) -> None:
        self.stereo, self.cfg = stereo, fusion
        self.sweep = sweep or dense_sweep.SweepConfig()
        self.facade = facade or dense_facade.FacadeConfig()
        self.fill = fill or dense_fill.FillConfig()
        self.ground = ground or dense_ground.GroundConfig()
        self._frames: dict[int, _Keyframe] = {}
        self.depth_computed = 0  # stereo pairs run so far (recomputations included)
        self.sweeps_computed = 0  # plane sweeps run so far
        self.backlog = False  # depth maps left for later by the per-update budget
        self._poses: dict[int, FloatArray] = {}
        self._voxels = dense_cloud.VoxelSums(fusion.voxel_m)

    def add_keyframe(self, stamp_ns: int, image_bgr: np.ndarray, camera: CameraModel) -> None:
        """Keep a keyframe (at the working scale) until its pose is known."""
        image, cam = dense_stereo.working_image(image_bgr, camera, self.stereo)
        fine = dense_facade.fine_view(image_bgr, camera) \
            if self.facade.enabled or self.ground.enabled else None
        self._frames[stamp_ns] = _Keyframe(image, cam, fine=fine)

    def update(self, poses: dict[int, FloatArray]) -> bool:
        """
        Take the latest metric poses (stamp -> T_world_cam); compute what they make stale.

        :returns: whether the cloud changed.
        """
        stamps = [s for s in sorted(self._frames) if s in poses]
        moved = stamps != getattr(self, '_stamps', [])
        for s in stamps:
            kf = self._frames[s]
            old, kf.pose = kf.pose, np.asarray(poses[s], np.float64)
            moved |= old is None or not np.allclose(old, kf.pose, atol=1e-9)
        # Clouds live in their keyframe's camera frame: a pose that moves only moves them.
        # Newest first, at most max_new_maps stereo pairs: a backlog (all keyframes when the
        # scale is first claimed) is spread over the following updates.
        self._budget, self.backlog, self._poses = self.cfg.max_new_maps, False, poses
        self._sweep_budget, self._facade_budget = 1, 1
        outcome, sweep_only = [1.0] * len(stamps), [False] * len(stamps)
        for i in reversed(range(len(stamps))):
            outcome[i], sweep_only[i] = self._refresh_depth(stamps, i)
        for i in reversed(range(len(stamps))):
            if self._refresh_facade(stamps, i) == _NEW:
                # its far points vote for the earlier neighbours' far points (which are fused
                # again when ``facade_revote``: several keyframe clouds per update), theirs for it
                revote = self.cfg.facade_revote
                for j in range(max(0, i - self.cfg.neighbours), i + 1):
                    if j == i or revote and FACADE in self._frames[stamps[j]].depths:
                        outcome[j], sweep_only[j] = _NEW, False
        builds: dict[int, Callable[[], Any]] = {}  # each reads the depth maps, writes its own
        for i, s in enumerate(stamps):
            kf = self._frames[s]
            if not kf.depths:
                kf.cloud, kf.placed = None, None
            elif sweep_only[i] and kf.cloud is not None and self._fill_pending(stamps, i):
                builds[s] = partial(self._with_sweep, kf.cloud, stamps, i)
            elif outcome[i] == _NEW or kf.cloud is None or \
                    not kf.filled and self._fill_ready(stamps, i):
                builds[s] = partial(self._keyframe_cloud, stamps, i)
            elif outcome[i] != 1.0:
                kf.cloud.scale(outcome[i], np.zeros(3))  # a new scale: depth x baseline ratio
                kf.placed = None
        for s, cloud in zip(builds, self._built(list(builds.values()))):
            self._frames[s].cloud, self._frames[s].placed = cloud, None
        self._stamps = stamps
        return moved or any(o != 1.0 for o in outcome)

    def _built(self, builds: list[Callable[[], Any]]) -> list[Any]:
        """The keyframe clouds of ``builds``, ``threads`` at once: numpy and OpenCV let go of
        the GIL in the consistency check (a new keyframe's first cloud and an older one's
        filled rebuild come in the same update)."""
        if self.cfg.threads < 2 or len(builds) < 2:
            return [build() for build in builds]
        with ThreadPoolExecutor(min(self.cfg.threads, len(builds))) as pool:
            return list(pool.map(lambda build: build(), builds))

    def catch_up(self) -> bool:
        """Work on the backlog with the latest poses; returns whether the cloud changed."""
        return self.backlog and self.update(self._poses)

    def _refresh_depth(self, stamps: list[int], i: int) -> tuple[float, bool]:
        """
        Bring keyframe ``i``'s depth maps (a partner on each side, or one) up to date: return
        ``_NEW`` if one was computed, else the factor its depths were rescaled by (1.0: none),
        and whether its sweep was the only map computed. Both sides average out SGBM's
        sub-pixel bias, whose sign follows the direction of the baseline in the image
        (measured on indoor 64's floor: -1.1 / +0.6 % of depth with ``stereo.mode`` 'sgbm').
        """
        results = [r for side in ((1, -1) if self.cfg.both_sides else (0,))
                   if (r := self._refresh_side(stamps, i, side)) is not None]
        depths = self._frames[stamps[i]].depths
        had_sweep = SWEEP in depths
        swept = self._refresh_sweep(stamps, i)
        # Only a first sweep beside unchanged pair maps may be added to the cloud as it is: a
        # rescaled pair, a re-sweep (old points still in the cloud) or a removed sweep rebuild.
        sweep_only = swept == _NEW and not had_sweep and SWEEP in depths and \
            all(r == 1.0 for r in results)
        if swept is not None:
            results.append(swept)
        return _NEW if _NEW in results else float(np.mean(results)) if results else 1.0, \
            sweep_only

    def _refresh_side(self, stamps: list[int], i: int, side: int) -> float | None:
        kf = self._frames[stamps[i]]
        old = kf.depths.get(side)
        if old is not None:
            ratio = self._rescale(kf, {old.pair_stamp: old.relative}, old)
            if ratio is not None:
                old.relative = dense_stereo.relative_pose(kf.pose,
                                                          self._frames[old.pair_stamp].pose)
                return ratio
        depth_guess = None  # only once a keyframe lies on this side (a walk to one side
        # leaves the other side empty, and each update asks again)
        n = self.stereo.candidates
        scored = []
        for j in range(max(0, i - n), min(len(stamps), i + n + 1)):
            other = self._frames[stamps[j]].pose
            offset = kf.pose[:3, :3].T @ (other[:3, 3] - kf.pose[:3, 3])
            if j != i and side in (0, np.sign(offset[0])):
                if depth_guess is None:
                    depth_guess = self._depth_guess(stamps, i)
                q = dense_stereo.pair_quality(kf.pose, other, depth_guess, self.stereo)
                if q is not None:
                    scored.append((q, j))
        if not scored:  # no partner on this side (any more)
            return _NEW if kf.depths.pop(side, None) is not None else None
        if self._budget <= 0:
            self.backlog = True
            return None  # left for a later update (``catch_up``)
        self._budget -= 1
        j = min(scored)[1]
        partner = self._frames[stamps[j]]
        kf.depths[side] = dense_stereo.compute_depth(kf.image, partner.image, kf.camera,
                                                     kf.pose, partner.pose, stamps[j],
                                                     self.stereo)
        self.depth_computed += 1
        return _NEW

    def _rescale(self, kf: _Keyframe, used: dict[int, FloatArray],
                 depth: dense_stereo.DepthMap | None) -> float | None:
        """
        If no view ``depth`` was computed with (stamp -> T_view_kf then) moved materially,
        rescale it by the change of scale and return the factor; None if it must be recomputed.
        """
        ratios = []
        for stamp, before in used.items():
            other = self._frames.get(stamp)
            if other is None or other.pose is None:
                return None
            T = dense_stereo.relative_pose(kf.pose, other.pose)
            if _rotation_deg(T[:3, :3] @ before[:3, :3].T) >= self.cfg.recompute_deg \
                    or _angle_deg(T[:3, 3], before[:3, 3]) >= self.cfg.recompute_deg:
                return None
            ratios.append(np.linalg.norm(T[:3, 3]) / np.linalg.norm(before[:3, 3]))
        ratio = float(np.mean(ratios))
        if abs(ratio - 1.0) < 1e-9:
            return 1.0
        if depth is not None:  # a new scale only: depth goes with the baselines
            depth.depth *= np.float32(ratio)
        return ratio

    def _refresh_sweep(self, stamps: list[int], i: int) -> float | None:
        """Keyframe ``i``'s plane-sweep depth map, once ``lag`` later keyframes exist."""
        cfg, kf = self.sweep, self._frames[stamps[i]]
        if not cfg.enabled or len(stamps) - 1 - i < cfg.lag:
            return None
        old = kf.depths.get(SWEEP)
        if old is not None and (ratio := self._rescale(kf, kf.swept_with, old)) is not None:
            kf.swept_with = {s: dense_stereo.relative_pose(kf.pose, self._frames[s].pose)
                             for s in kf.swept_with}
            return ratio
        guess = self._depth_guess(stamps, i)
        scored = []
        for j in range(max(0, i - cfg.span), min(len(stamps), i + cfg.span + 1)):
            T = dense_stereo.relative_pose(kf.pose, self._frames[stamps[j]].pose)
            baseline = float(np.linalg.norm(T[:3, 3]))
            if j != i and baseline >= cfg.min_baseline_ratio * guess and \
                    _rotation_deg(T[:3, :3]) <= cfg.max_angle_deg:
                scored.append((abs(np.log(baseline / guess / self.stereo.target_baseline_ratio)),
                               stamps[j], T))
        if not scored:
            kf.swept_with = {}
            return _NEW if kf.depths.pop(SWEEP, None) is not None else None
        if self._sweep_budget <= 0:
            self.backlog = True
            return None
        self._sweep_budget -= 1
        chosen = sorted(scored, key=lambda x: x[0])[:cfg.views]
        kf.depths[SWEEP] = self._swept(stamps, i, [(s, T) for _, s, T in chosen], guess)
        kf.swept_with = {s: T for _, s, T in chosen}
        self.sweeps_computed += 1
        return _NEW

    def _swept(self, stamps: list[int], i: int, views: list[tuple[int, FloatArray]],
               guess: float) -> dense_stereo.DepthMap:
        """The plane sweep of keyframe ``i`` over ``views`` (stamp, T_view_kf)."""
        frames = [self._frames[stamps[i]]] + [self._frames[s] for s, _ in views]
        for f in frames:
            if f.view is None:
                f.view = dense_sweep.pinhole_view(f.image, f.camera, self.sweep)
        colour, grey, K = frames[0].view
        near, far = self._depth_range(stamps, i, guess)
        plane = dense_sweep.dominant_plane(self._nearby_points(stamps, i), self.sweep) \
            if self.sweep.plane else None
        depth = dense_sweep.sweep(grey, [(f.view[1], T) for f, (_, T) in zip(frames[1:], views)],
                                  K, near, far, self.sweep, plane)
        if self.sweep.edge_jump > 0.0:
            depth[dense_sweep.depth_edges(depth, self.sweep.edge_jump,
                                          self.sweep.edge_radius_px)] = 0.0
        centres = [-T[:3, :3].T @ T[:3, 3] for _, T in views]
        depth[~dense_sweep.precise(depth, K, centres, self.sweep.max_depth_baselines,
                                   self.sweep.max_step_m)] = 0.0
        return dense_stereo.DepthMap(depth, colour, K, np.eye(3), -1, np.eye(4))

    def _refresh_facade(self, stamps: list[int], i: int) -> float | None:
        """Keyframe ``i``'s far-plane depth map, once it is swept (``dense_facade``)."""
        cfg, kf = self.facade, self._frames[stamps[i]]
        if not cfg.enabled or kf.view is None or SWEEP not in kf.depths or i % cfg.every \
                or len(stamps) - 1 - i < cfg.lag:  # its pairs done, later far views there
            return None
        if kf.facade_with:
            ratio = self._rescale(kf, kf.facade_with, kf.depths.get(FACADE))
            if ratio is not None:
                kf.facade_with = {s: dense_stereo.relative_pose(kf.pose, self._frames[s].pose)
                                  for s in kf.facade_with}
                kf.planes = [(p / ratio, n) for p, n in kf.planes]
                return ratio
        poses = [self._frames[s].pose for s in stamps]
        views = dense_facade.far_views(poses, i, cfg, self.sweep.max_angle_deg)
        if not views:
            return None
        if self._facade_budget <= 0:
            self.backlog = True
            return None
        self._facade_budget -= 1
        others, fine = [], []
        for j, T in views:
            other = self._frames[stamps[j]]
            if other.view is None:
                other.view = dense_sweep.pinhole_view(other.image, other.camera, self.sweep)
            others.append((other.view[1], T))
            fine.append((other.fine[0].astype(np.float32), T))
        colour, grey, K = kf.view
        covered = self._covered(kf)
        if cfg.occluders > 0:
            covered |= self._occluded(stamps, i)
        fine_ref = (kf.fine[0].astype(np.float32), fine, kf.fine[1])
        planes = dense_facade.facade_planes(grey, others, K, covered, cfg, self.sweep, fine_ref)
        kf.planes = [(p, n) for p, _, n in planes if n > 0]
        kf.facade_with = {stamps[j]: T for j, T in views}
        known = [(dense_facade.world_plane(p, f.pose), n)
                 for s in stamps[max(0, i - cfg.span):i + cfg.span + 1]
                 if (f := self._frames[s]) is not kf for p, n in f.planes]
        use = [(dense_facade.pooled(p, kf.pose, known, cfg), region) for p, region, _ in planes]
        depth = dense_facade.facade_fill(grey, others, K, covered, use, cfg, fine_ref)
        if depth.any():
            kf.depths[FACADE] = dense_stereo.DepthMap(depth, colour, K, np.eye(3), -1, np.eye(4))
        elif kf.depths.pop(FACADE, None) is None:
            return None
        return _NEW

    def _covered(self, kf: _Keyframe) -> npt.NDArray[np.bool_]:
        """Pixels of the keyframe's sweep view that its other depth maps cover."""
        _, grey, K = kf.view
        return _pixels_hit([m.points_camera()[0] for m in _measured(kf)], K, grey.shape)

    def _occluded(self, stamps: list[int], i: int, stride: int = 2) -> npt.NDArray[np.bool_]:
        """
        Pixels of keyframe ``i``'s sweep view where a neighbour's measured points lie nearer
        than the far planes begin: something stands in front of any façade there (a post, a
        tree its own maps missed), which a plain or repeating patch can hide from the fill
        check.
        """
        _, grey, K = self._frames[stamps[i]].view
        pts = self._neighbour_points(stamps, i, self.facade.occluders, stride, others_only=True)
        return _pixels_hit([pts[(pts[:, 2] > 1e-6) & (pts[:, 2] < self.facade.near_m)]], K,
                           grey.shape)

    def _nearby_points(self, stamps: list[int], i: int, stride: int = 8) -> FloatArray:
        """A thinned sample of the depth maps of keyframe ``i`` and its neighbours, in its
        camera frame (where a dominant plane is looked for)."""
        return self._neighbour_points(stamps, i, self.sweep.span, stride)

    def _neighbour_points(self, stamps: list[int], i: int, span: int, stride: int,
                          others_only: bool = False) -> FloatArray:
        """Every ``stride``-th point of the measured depth maps of the keyframes within
        ``span`` of keyframe ``i`` (without its own when ``others_only``), in its camera frame."""
        kf, out = self._frames[stamps[i]], []
        for s in stamps[max(0, i - span):i + span + 1]:
            other = self._frames[s]
            if others_only and other is kf:
                continue
            T = dense_stereo.relative_pose(other.pose, kf.pose)  # other camera -> kf camera
            for m in _measured(other):
                out.append(dense_stereo.transform(m.points_camera(stride)[0], T[:3, :3],
                                                  T[:3, 3]))
        return np.concatenate(out) if out else np.zeros((0, 3))

    def _depth_range(self, stamps: list[int], i: int, guess: float) -> tuple[float, float]:
        """Depths to sweep: what the depth maps of nearby keyframes hold, widened."""
        span = self.sweep.span
        depths = [d.depth[d.depth > 0][::7] for s in stamps[max(0, i - span):i + span + 1]
                  for d in _measured(self._frames[s])]
        values = np.concatenate(depths) if depths else np.zeros(0)
        if values.size < 100:
            return guess / 4.0, guess * 4.0
        near, far = np.percentile(values, [1, 99])
        return float(near) / 1.5, float(far) * 1.5

    def _depth_guess(self, stamps: list[int], i: int) -> float:
        """Median depth of the nearest keyframe that has a depth map (for the pair choice)."""
        for j in sorted(range(len(stamps)), key=lambda j: abs(j - i)):
            for d in _measured(self._frames[stamps[j]]):
                if np.any(d.depth > 0):
                    return float(np.median(d.depth[d.depth > 0]))
        return 1.0 / self.stereo.target_baseline_ratio * self._typical_step(stamps, i)

    def _typical_step(self, stamps: list[int], i: int) -> float:
        """Distance to the nearest other keyframe: keyframes are about a target ratio apart."""
        c = self._frames[stamps[i]].pose[:3, 3]
        steps = [np.linalg.norm(self._frames[s].pose[:3, 3] - c) for s in stamps if s != stamps[i]]
        return float(min(steps)) if steps else 1.0

    def _keyframe_cloud(self, stamps: list[int], i: int) -> Any:
        """The consistent points of keyframe ``i``, cleaned, with normals, in its camera frame."""
        kf = self._frames[stamps[i]]
        keep_pts, keep_col = self._consistent(stamps, i, sorted(kf.depths))  # sweep after pairs
        kf.filled = self._fill_ready(stamps, i)
        if kf.filled and self.fill.enabled:  # plain holes on a plane around them
            pts, colours = self._filled(stamps, i, np.concatenate(keep_pts))
            keep_pts.append(pts)
            keep_col.append(colours)
        ground = self._grounded(stamps, i, np.concatenate(keep_pts)) \
            if kf.filled and self.ground.enabled else None  # the ground beyond stereo's reach
        if ground is not None and not self.ground.apart:
            keep_pts.append(ground[0])
            keep_col.append(ground[1])
            ground = None
        cloud = dense_cloud.clean(np.concatenate(keep_pts), np.concatenate(keep_col), self.cfg)
        if ground is None or not len(ground[0]):
            return cloud
        # its far rows are sparse by nature: the statistical test would take them for outliers
        extra = dense_cloud.clean(*ground, replace(self.cfg, outlier_std=0.0))
        return cloud + extra if extra.has_normals() else cloud

    def _fill_pending(self, stamps: list[int], i: int) -> bool:
        """Whether keyframe ``i``'s plain holes are still to be filled, and so its cloud is
        still to be rebuilt whole (``_fill_ready``)."""
        return self._plane_fills() and not self._frames[stamps[i]].filled and \
            len(stamps) - 1 - i < self._fill_lag()

    def _with_sweep(self, cloud: Any, stamps: list[int], i: int) -> Any:
        """
        Keyframe ``i``'s cloud with the points of its new sweep added (cleaned on their own).

        Its pairs' points are left as they are, without the sweep's votes and averaging: the
        rebuild when its holes are filled (``fill.lag`` later) checks every point again, so
        checking them now as well would only cost an update its CPU twice.
        """
        pts, colours = self._consistent(stamps, i, [SWEEP])
        extra = dense_cloud.clean(np.concatenate(pts), np.concatenate(colours), self.cfg)
        return cloud + extra if extra.has_normals() else cloud

    def _consistent(self, stamps: list[int], i: int,
                    sides: list[int]) -> tuple[list[FloatArray], list[npt.NDArray[np.uint8]]]:
        """The points (camera frame) and colours of keyframe ``i``'s depth maps ``sides``
        that enough other depth maps agree with, per map."""
        kf = self._frames[stamps[i]]
        k = self.cfg.neighbours
        near = sorted(range(max(0, i - k), min(len(stamps), i + k + 1)), key=lambda j: abs(j - i))
        maps = [(m, self._frames[stamps[j]].pose, side >= SWEEP) for j in near
                for side, m in self._frames[stamps[j]].depths.items()]
        pairs = [m for side, m in kf.depths.items() if side < SWEEP]
        keep_pts, keep_col = [], []
        for side in sides:
            own = kf.depths[side]
            pts, colours = own.points_camera()
            world = dense_stereo.affine(pts, kf.pose[:3, :3], kf.pose[:3, 3])
            if side >= SWEEP:  # only where no pair (nor the sweep) of this keyframe has depth
                free = np.ones(len(pts), bool)
                for m in pairs:
                    free[_agreeing_index(world, kf.pose, m, np.inf)[0]] = False
                pts, colours, world = pts[free], colours[free], world[free]
            rel = self.cfg.facade_rel if side == FACADE else self.cfg.consistency_rel
            votes = np.zeros(len(pts), np.int32)
            total, weight = world.copy(), np.ones(len(pts))
            for m, pose, swept in maps:  # the keyframe's other side is an independent pair too
                # The other map's estimate of the same surface point, along its own ray:
                # averaging independent pairs shrinks SGBM's sub-pixel noise. A coarser
                # sweep only votes for a pair's points (those still short of votes).
                mean = self.cfg.average and (side >= SWEEP or not swept
                                             or self.cfg.sweep_average)
                if m is own:
                    continue
                if mean:
                    idx, ratio = _agreeing_index(world, pose, m, rel)
                    along = world[idx]  # its estimate: along its ray, scaled by the ratio
                    along -= pose[:3, 3]
                    along *= ratio[:, None]
                    along += pose[:3, 3]
                    total[idx] += along
                    weight[idx] += 1.0
                else:
                    short = np.flatnonzero(votes < self.cfg.min_consistent)
                    if not len(short):
                        continue
                    idx = short[_agreeing_index(world[short], pose, m, rel)[0]]
                votes[idx] += 1
            needed = {SWEEP: self.cfg.sweep_consistent, FACADE: self.cfg.facade_consistent}.get(
                side, self.cfg.min_consistent)
            keep = votes >= needed
            if self.cfg.average:
                world = total / weight[:, None]
                pts = dense_stereo.project(world, kf.pose[:3, :3].T, kf.pose[:3, 3])
            keep_pts.append(pts[keep])
            keep_col.append(colours[keep])
        return keep_pts, keep_col

    def _fill_ready(self, stamps: list[int], i: int) -> bool:
        """Whether keyframe ``i``'s plain holes are filled: once ``fill.lag`` later keyframes
        exist, its neighbourhood (planes, votes) is whole; filled earlier, from the keyframes
        before it alone, planes fitted to one side's points filled indoor 65 wrongly."""
        return self._plane_fills() and self._frames[stamps[i]].view is not None and \
            len(stamps) - 1 - i >= self._fill_lag()

    def _plane_fills(self) -> bool:
        """Whether a keyframe's cloud gets plane fills once its neighbourhood is whole."""
        return self.fill.enabled or self.ground.enabled

    def _fill_lag(self) -> int:
        """Later keyframes needed before the plane fills (the longest lag of those on)."""
        return max(self.fill.lag if self.fill.enabled else 0,
                   self.ground.lag if self.ground.enabled else 0)

    def _filled(self, stamps: list[int], i: int,
                kept: FloatArray) -> tuple[FloatArray, npt.NDArray[np.uint8]]:
        """Points (camera frame) and colours for keyframe ``i``'s plain holes among its
        ``kept`` points, on the planes of its neighbourhood's depth (``dense_fill``)."""
        colour, grey, K = self._frames[stamps[i]].view
        nearby = self._nearby_points(stamps, i, self.fill.stride)
        planes = dense_fill.scene_planes(nearby, self.fill)
        depth = dense_fill.fill(dense_fill.depth_image(kept, K, grey.shape), grey, K, planes,
                                self.fill, nearby)
        pts, v, u = dense_stereo.back_project(depth, K)
        return pts, colour[v, u]

    def _grounded(self, stamps: list[int], i: int,
                  kept: FloatArray) -> tuple[FloatArray, npt.NDArray[np.uint8]]:
        """Points (camera frame) and colours for keyframe ``i``'s ground beyond its ``kept``
        points, on the near ground's plane where views around it agree (``dense_ground``)."""
        cfg, kf = self.ground, self._frames[stamps[i]]
        colour, grey, K = kf.view
        nearby = self._neighbour_points(stamps, i, self.sweep.span, cfg.stride)
        p = dense_ground.ground_plane(nearby, cfg)
        none = np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
        if p is None:
            return none
        blocked = dense_fill.depth_image(kept, K, grey.shape) > 0
        blocked = cv2.dilate(blocked.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        blocked |= dense_ground.occupied(nearby, p, K, grey.shape, cfg.front_rel)
        z = dense_ground.candidates(p, K, blocked, cfg)
        if not z.any():
            return none
        views = dense_ground.check_views([self._frames[s].pose for s in stamps], i,
                                         float(np.median(z[z > 0])), cfg)
        if len(views) < cfg.fill_views:
            return none
        fine = (kf.fine[0].astype(np.float32),
                [(self._frames[stamps[j]].fine[0].astype(np.float32), T) for j, T in views],
                kf.fine[1])
        depth = dense_ground.fill(grey, fine, K, z, p, cfg)
        pts, v, u = dense_stereo.back_project(depth, K)
        return pts, colour[v, u]

    def cloud(self) -> tuple[FloatArray, npt.NDArray[np.uint8], FloatArray]:
        """
        The fused cloud in the world frame: (N, 3) metres, (N, 3) rgb, (N, 3) unit normals.

        Incremental: only keyframes whose cloud is new or rescaled, or whose pose moved their
        points by more than ``move_voxels`` voxels, are put into the voxels again.
        """
        live = set()
        for s in getattr(self, '_stamps', []):
            kf = self._frames[s]
            if kf.cloud is None:
                continue
            live.add(s)
            if kf.placed is None or self._moves(kf) > self.cfg.move_voxels * self.cfg.voxel_m:
                self._voxels.set(s, kf.cloud, kf.pose)
                kf.placed = kf.pose.copy()
                kf.reach = float(np.max(np.linalg.norm(np.asarray(kf.cloud.points), axis=1),
                                        initial=0.0))
        for s in set(self._voxels.parts) - live:
            self._voxels.remove(s)
        return self._voxels.cloud()

    @staticmethod
    def _moves(kf: _Keyframe) -> float:
        """How far at most the pose moved any point of the keyframe from where it is fused."""
        step = float(np.linalg.norm(kf.pose[:3, 3] - kf.placed[:3, 3]))
        turn = np.radians(_rotation_deg(kf.pose[:3, :3] @ kf.placed[:3, :3].T))
        return step + turn * kf.reach

    @property
    def pairs(self) -> list[tuple[int, int]]:
        """(keyframe, partner) stamps of every depth map held."""
        return [(s, d.pair_stamp) for s, kf in sorted(self._frames.items())
                for side, d in kf.depths.items() if side < SWEEP]

    @property
    def keyframes(self) -> int:
        """Keyframes whose points are in the cloud."""
        return sum(1 for s in getattr(self, '_stamps', []) if self._frames[s].cloud is not None)


def agreeing(world: FloatArray, T_world_cam: FloatArray, depth: dense_stereo.DepthMap,
             tolerance_rel: float) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.float32]]:
    """
    Which world points the depth map of another keyframe sees at the same depth, and the
    ratio of its depth to theirs along its rays (valid where they agree).
    """
    idx, ratio = _agreeing_index(world, T_world_cam, depth, tolerance_rel)
    ok = np.zeros(len(world), bool)
    ok[idx] = True
    out = np.ones(len(world), np.float32)
    out[idx] = ratio
    return ok, out


def _agreeing_index(world: FloatArray, T_world_cam: FloatArray, depth: dense_stereo.DepthMap,
                    tolerance_rel: float) -> tuple[npt.NDArray[np.intp], FloatArray]:
    """``agreeing`` as the indices of the agreeing points and their ratios (the fusion's
    inner loop: each step runs once over all points, no (N, 3) gathers)."""
    p = dense_stereo.project(world, depth.K_rect @ depth.R_rect @ T_world_cam[:3, :3].T,
                             T_world_cam[:3, 3])  # u z, v z, z
    z = p[:, 2]
    h, w = depth.depth.shape
    with np.errstate(divide='ignore', invalid='ignore'):  # behind the camera: left out below
        u, v = np.rint(p[:, 0] / z), np.rint(p[:, 1] / z)
    idx = np.flatnonzero((z > 1e-6) & (u >= 0) & (u < w) & (v >= 0) & (v < h))
    z = z[idx]
    seen = depth.depth.ravel()[v[idx].astype(np.intp) * w + u[idx].astype(np.intp)]
    good = (seen > 0) & (np.abs(seen - z) <= tolerance_rel * z)
    return idx[good], seen[good] / z[good]


def pose_matrices(poses_xyzw: FloatArray, stamps_ns: npt.ArrayLike) -> dict[int, FloatArray]:
    """stamp -> 4x4 T_world_cam from (N, 7) ``x y z qx qy qz qw`` rows (a Path's poses)."""
    from scipy.spatial.transform import Rotation
    out = {}
    for stamp, p in zip(np.asarray(stamps_ns).tolist(), np.asarray(poses_xyzw, np.float64)):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = Rotation.from_quat(p[3:]).as_matrix(), p[:3]
        out[int(stamp)] = T
    return out
