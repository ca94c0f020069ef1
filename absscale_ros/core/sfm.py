"""
Incremental structure from motion over keyframes (paper Step 3), one call per keyframe.

State is explicit: ``IncrementalSfm`` holds the map segments. A keyframe is registered by PnP
against the landmarks its features match in the last few keyframes; if that fails it is
relocalised against the whole segment; if that fails too a new segment is started (the old one
is kept unchanged). A pose or an initial pair that a repeated texture may have produced (see
``aliasing``, ``twoview.initialise``) counts as a failure: a new segment beats a bent map. New
landmarks are triangulated with the matched keyframes, and the segment's ``SegmentGraph``
(GTSAM) refines everything.
"""
from collections.abc import Callable
from dataclasses import dataclass, field, fields, is_dataclass, replace
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import aliasing, errors, keyframes, landmark_quality, local_map, sfm_graph
from absscale_ros.core import landmark_refine, sfm_map, sfm_refine
from absscale_ros.core import sfm_vertices, twoview
from absscale_ros.core import features as feat
from absscale_ros.core import vertex_matching as vm
from absscale_ros.core.types import CameraModel

FloatArray = npt.NDArray[np.float64]
Progress = Callable[[str, float], None]


@dataclass(frozen=True)
class SfmConfig:
    """Settings of the incremental driver and its stages."""

    feature_cfg: feat.FeatureConfig = field(default_factory=feat.FeatureConfig)
    twoview_cfg: twoview.TwoViewConfig = field(default_factory=twoview.TwoViewConfig)
    graph_cfg: sfm_graph.GraphConfig = field(default_factory=sfm_graph.GraphConfig)
    vertex_cfg: vm.VertexMatchConfig = field(default_factory=vm.VertexMatchConfig)
    local_cfg: local_map.LocalMapConfig = field(default_factory=local_map.LocalMapConfig)
    cloud_cfg: landmark_quality.CloudConfig = field(
        default_factory=landmark_quality.CloudConfig)  # what the published cloud keeps
    refine_cfg: landmark_refine.RefineConfig = field(
        default_factory=landmark_refine.RefineConfig)  # full-resolution observation refinement
    match_window: int = 3  # match each new keyframe against this many previous ones
    relocalise_window: int = 30  # keyframes tried when the recent ones do not register it
    min_pnp_inliers: int = 30
    pnp_px: float = 2.0  # PnP RANSAC reprojection threshold, px
    # A keyframe that the recent keyframes do not register at ``pnp_px`` tries again at this
    # threshold once the segment has ``retry_min_keyframes`` (0: never). A young map moving
    # towards the scene holds landmarks a few px off (the indoor sample: 26 of 69 inliers at
    # 2 px, and a split); the pose still passes every aliasing check. Never on a two-view
    # pair: the next keyframe failing on it is what drops a weak or aliased pair.
    retry_pnp_px: float = 3.0
    retry_min_keyframes: int = 4
    max_pending: int = 6  # keyframes kept while waiting for a well-conditioned initial pair
    max_failures: int = 2  # consecutive unregistrable keyframes (dropped) before a new segment
    match_unclaimed_only: bool = False  # older neighbours see only keypoints still unmatched
    # A registration whose velocity (since the newest keyframe) differs from the velocity
    # before by more than this times the faster of the two is refused when the three keyframes
    # span at most ``motion_check_s``: a camera does not reverse in a fraction of a second, but
    # a repeated texture (pavers) matched one period off moves the pose by that period.
    max_velocity_change: float = 1.2  # (0: off; a reversal at equal speed is 2, a right turn 1.4)
    motion_check_s: float = 1.0
    # ... unless both steps are shorter than this share of the segment's median step: a camera
    # nearly still moves by pose noise, which reverses its velocity at random (the 60 s bag's
    # standstills broke its segments at 75 keyframes); an aliased pose jumps a texture period.
    slow_step_share: float = 0.3
    # A pose that the correspondences off their dominant plane support less than this share
    # as well as those on it (their inlier rates) is refused, given ``min_off_plane`` of them:
    # the texture's plane carries an aliased pose, the rest of the scene does not (0: off).
    min_off_plane_support: float = 0.35
    min_off_plane: int = 20
    plane_tol: float = 0.02  # plane thickness / median spread of the landmarks
    plane_check_px: float = 8.0  # a correspondence this close to the pose supports it, px
    # A registration whose step points more than this away from the step the keyframe
    # selector tracked (corners followed frame to frame: a few pixels each, which a repeated
    # texture cannot fool) is refused. The tracked direction itself was off by up to 94
    # degrees in simulator bags (an essential matrix on a short baseline); an aliased pose
    # pointed backwards (178). 180: off.
    max_tracked_angle_deg: float = 120.0

    def __post_init__(self) -> None:
        if self.match_window < 1 or self.relocalise_window < self.match_window or \
                self.min_pnp_inliers < 6 or self.pnp_px <= 0.0 or self.max_pending < 2 or \
                self.retry_pnp_px < 0.0 or self.retry_min_keyframes < 3 or \
                min(self.max_velocity_change, self.motion_check_s, self.min_off_plane_support,
                    self.slow_step_share, self.plane_tol, self.plane_check_px) < 0.0 or \
                self.min_off_plane < 1 or not 0.0 < self.max_tracked_angle_deg <= 180.0:
            raise ValueError(f'bad sfm config {self}')


# ROS parameter prefix of each nested config of SfmConfig (``features.ratio`` is
# feature_cfg.ratio): the sfm node declares them, `bench sfm --config` reads a file with them.
PARAM_PREFIXES = {'features': 'feature_cfg', 'twoview': 'twoview_cfg', 'graph': 'graph_cfg',
                  'vertices': 'vertex_cfg', 'local_map': 'local_cfg', 'cloud': 'cloud_cfg',
                  'refine': 'refine_cfg'}


def config_from_params(flat: dict[str, Any]) -> SfmConfig:
    """SfmConfig from an sfm node's parameters (dotted names); others are ignored."""
    cfg = SfmConfig()
    values: dict[str, Any] = {f.name: flat[f.name] for f in fields(cfg)
                              if not is_dataclass(getattr(cfg, f.name)) and f.name in flat}
    for prefix, attr in PARAM_PREFIXES.items():
        sub = getattr(cfg, attr)
        found = {f.name: flat[f'{prefix}.{f.name}'] for f in fields(sub)
                 if f'{prefix}.{f.name}' in flat}
        values[attr] = replace(sub, **{
            k: tuple(v) if isinstance(getattr(sub, k), tuple) else v for k, v in found.items()})
    return replace(cfg, **values)


@dataclass(frozen=True)
class UpdateResult:
    """What one keyframe did: ``status`` is pending, initialised, registered, relocalised,
    new_segment or rejected; ``message`` says why in words. ``reprojection_rms_px`` is over the
    newest ``match_window`` keyframes' observations (the whole segment after ``finish``)."""

    status: str
    message: str
    keyframes: int
    landmarks: int
    reprojection_rms_px: float
    segments: int


@dataclass
class Segment:
    map: sfm_map.SfmMap
    graph: sfm_graph.SegmentGraph
    pending: list[sfm_map.MapKeyframe] = field(default_factory=list)  # before initialisation
    forgotten: int = 0  # keyframes (oldest first) whose descriptors were dropped
    released: bool = False  # finished, and its iSAM2 state let go

    @property
    def initialised(self) -> bool:
        return len(self.map.keyframes) >= 2


class IncrementalSfm:
    """Keyframes in, a growing (unscaled) reconstruction out."""

    def __init__(self, camera: CameraModel, cfg: SfmConfig, rng: np.random.Generator,
                 progress: Progress | None = None) -> None:
        self.camera, self.cfg, self._rng, self._progress = camera, cfg, rng, progress
        self.K = camera.K
        self.segments: list[Segment] = [self._new_segment()]
        self._next_kf = 0
        self._failures = 0
        self._steps: dict[int, keyframes.TrackedStep] = {}  # of the newest keyframes, by stamp
        self._refiner = sfm_refine.ObservationRefiner(camera, cfg.refine_cfg)

    def _new_segment(self) -> Segment:
        return Segment(sfm_map.SfmMap(), sfm_graph.SegmentGraph(self.K, self.cfg.graph_cfg))

    @property
    def current(self) -> Segment:
        return self.segments[-1]

    def detect(self, image_bgr: npt.NDArray[np.uint8]) -> feat.Features:
        """The features ``add_keyframe`` would detect in ``image_bgr`` (no state touched: a
        worker thread may run it ahead while the previous keyframe is processed; OpenCV
        releases the GIL)."""
        return feat.detect(image_bgr, self.camera, self.cfg.feature_cfg)

    def add_keyframe(self, stamp_ns: int, image_bgr: npt.NDArray[np.uint8],
                     vertices: vm.Vertices | None = None,
                     step: keyframes.TrackedStep | None = None,
                     features: feat.Features | None = None,
                     defer_batch: bool = False) -> UpdateResult:
        """
        Process one keyframe; see ``UpdateResult``.

        :param image_bgr: (H, W, 3) uint8 image.
        :param vertices: its detected target vertices, ``points_px`` distorted (as detected).
        :param step: its motion from the previous keyframe as the keyframe selector tracked it
            (None: unknown); a pose that disagrees with it is refused.
        :param features: ``detect(image_bgr)`` if already computed (None: detected here).
        :param defer_batch: leave a due batch adjustment to ``adjust_if_due`` (live: run once
            this keyframe is published and no newer one waits; it costs seconds).
        """
        if step is not None:
            self._steps[stamp_ns] = step
            while len(self._steps) > self.cfg.max_failures + 2:  # enough to bridge drops
                del self._steps[min(self._steps)]
        f = self.detect(image_bgr) if features is None else features
        kf = sfm_map.MapKeyframe(self._next_kf, stamp_ns, np.eye(4), f,
                                 np.full(len(f.points_px), -1, np.int64))
        if vertices is not None and len(vertices.object_ids):
            undistorted = replace(vertices,
                                  points_px=feat.undistort_px(self.camera, vertices.points_px))
            kf.vertices = sfm_vertices.make(undistorted, image_bgr, self.cfg.vertex_cfg)
        self._next_kf += 1
        self._refiner.add_image(kf.kf_id, image_bgr)
        seg = self.current
        if not seg.initialised:
            status, msg = self._try_initialise(seg, kf)
        else:
            status, msg = self._register(seg, kf)
        if status in ('registered', 'relocalised') and not defer_batch and \
                seg.graph.batch_due(len(seg.map.keyframes)):
            culled = seg.graph.batch(seg.map, self._progress)
            msg += f'; batch adjustment culled {culled} landmarks'
        self._forget_descriptors()
        self._refiner.keep(set(self.current.map.keyframes) |
                           {p.kf_id for p in self.current.pending})
        return self._result(status, msg)

    def adjust_if_due(self, stop: Callable[[], bool] | None = None) -> int | None:
        """The batch adjustment ``defer_batch`` left out, if the current segment is due one:
        the landmarks it culled (None: not due). ``stop``: see ``SfmGraph.batch``."""
        seg = self.current
        if not seg.initialised or not seg.graph.batch_due(len(seg.map.keyframes)):
            return None
        return seg.graph.batch(seg.map, self._progress, stop)

    def _forget_descriptors(self) -> None:
        """
        Drop the features (descriptors ~1 MB a keyframe, keypoints and their colours
        ~70 KB; the landmark of each keypoint stays) of keyframes no match can reach any
        more: all but the newest of the current segment (registration, relocalisation and the
        local map look no further back) and all of the finished segments, whose iSAM2 state
        goes too (``finish`` adjusts them from their maps).
        """
        keep = max(self.cfg.match_window, self.cfg.relocalise_window,
                   self.cfg.local_cfg.keyframes, self.cfg.max_pending)
        for seg in self.segments:
            if seg.released:
                continue  # finished: everything was dropped when it was released
            ids = sorted(seg.map.keyframes)
            upto = len(ids) if seg is not self.current else max(0, len(ids) - keep)
            for kf_id in ids[seg.forgotten:upto]:
                kf = seg.map.keyframes[kf_id]
                kf.features = _forgotten(kf.features)
            seg.forgotten = max(seg.forgotten, upto)
            if seg is not self.current and not seg.released:
                seg.graph.release()  # a finished segment's iSAM2 (~100 MB) until ``finish``
                seg.released = True

    def finish(self) -> UpdateResult:
        """Final batch adjustment of every initialised segment; the result of the current one."""
        for seg in self.segments:
            if seg.initialised:
                self._link_back(seg.map)
                seg.graph.batch(seg.map, self._progress, converged=True)
        return self._result('finished', f'{len(self.segments)} segment(s) adjusted', True)

    def _link_back(self, m: sfm_map.SfmMap) -> int:
        """
        Before the final batch, each keyframe still holding its descriptors looks for the
        landmarks of ``local_cfg.final_keyframes`` neighbours on each side (the guided search
        during the run only links a new keyframe to older landmarks, never an older keyframe
        to the landmarks triangulated after it); returns the observations added. Only the
        newest keyframes of the current segment still hold descriptors (30 in the configs, see
        ``_forget_descriptors``), so a longer map's early keyframes are not reached: linking
        each keyframe as it forgets its descriptors would reach them (not done yet).
        """
        w = self.cfg.local_cfg.final_keyframes
        ids = [i for i in sorted(m.keyframes) if len(m.keyframes[i].features.descriptors)]
        added, size = 0, (self.camera.width, self.camera.height)
        cfg = replace(self.cfg.local_cfg, radius_px=self.cfg.local_cfg.final_radius_px)
        for n, i in enumerate(ids if w > 0 else []):
            others = [m.keyframes[j] for j in ids[max(0, n - w):n + w + 1] if j != i][::-1]
            added += local_map.search(m, self.K, m.keyframes[i], size, cfg, others)
        return added

    def _result(self, status: str, msg: str, full: bool = False) -> UpdateResult:
        m = self.current.map
        # Per keyframe, the RMS over the newest keyframes (O(1) as the map grows); ``finish``
        # gives the whole segment's.
        recent = None if full else set(sorted(m.keyframes)[-self.cfg.match_window:])
        return UpdateResult(status, msg, len(m.keyframes), len(m.landmarks),
                            m.reprojection_rms_px(self.K, recent), len(self.segments))

    def _verified(self, a: feat.Features, b: feat.Features,
                  b_subset: npt.NDArray[np.int64] | None = None,
                  b_index: feat.Index | None = None) -> npt.NDArray[np.int64]:
        pairs = feat.match(a, b, self.cfg.feature_cfg, b_subset, b_index)
        if len(pairs) == 0:
            return pairs
        ok = feat.verify(a.points_px[pairs[:, 0]], b.points_px[pairs[:, 1]],
                         self.cfg.feature_cfg, self._rng)
        return pairs[ok]

    def _try_initialise(self, seg: Segment, kf: sfm_map.MapKeyframe) -> tuple[str, str]:
        reason = 'first keyframe of the segment'
        # One index of kf for all pending keyframes (its build reseeds cv2's RNG to 0, and
        # ``twoview.initialise`` seeds its own: the same matches and pairs as one per pair).
        kf_index = feat.Index(kf.features.descriptors, self.cfg.feature_cfg) \
            if seg.pending else None
        for first in seg.pending:
            pairs = self._verified(first.features, kf.features, None, kf_index)
            try:
                T_b, pts, ok = twoview.initialise(
                    self.K, first.features.points_px[pairs[:, 0]],
                    kf.features.points_px[pairs[:, 1]], self.cfg.twoview_cfg, self._rng)
            except errors.DegenerateGeometryError as err:
                reason = f'not initialised: {err}'
                continue
            first.T_world_cam, kf.T_world_cam = np.eye(4), T_b
            seg.map.keyframes[first.kf_id] = first
            seg.map.keyframes[kf.kf_id] = kf
            self._add_points(seg.map, first, kf, pairs[ok], pts[ok])
            sfm_vertices.link(seg.map, self.K, kf, [first], self.cfg.twoview_cfg,
                              self.cfg.vertex_cfg)
            seg.pending.clear()
            seg.graph.update(seg.map)
            seg.graph.batch(seg.map, self._progress)
            return 'initialised', f'two-view initialisation with {int(ok.sum())} points'
        seg.pending = (seg.pending + [kf])[-self.cfg.max_pending:]
        return 'pending', reason

    def _add_points(self, m: sfm_map.SfmMap, a: sfm_map.MapKeyframe, b: sfm_map.MapKeyframe,
                    pairs: npt.NDArray[np.int64], points_world: FloatArray) -> None:
        colours = a.features.colours_rgb[pairs[:, 0]].tolist() if len(pairs) else []
        for (i, j), p, rgb in zip(pairs.tolist(), points_world, colours):
            lm_id = m.add_landmark(p, tuple(rgb))
            m.observe(lm_id, a.kf_id, a.features.points_px[i], i)
            m.observe(lm_id, b.kf_id, b.features.points_px[j], j)

    def _register(self, seg: Segment, kf: sfm_map.MapKeyframe) -> tuple[str, str]:
        ids, why = sorted(seg.map.keyframes), ''
        for status, window in (('registered', self.cfg.match_window),
                               ('relocalised', self.cfg.relocalise_window)):
            neighbours = [seg.map.keyframes[i] for i in ids[-window:]][::-1]
            if status == 'relocalised':
                neighbours = neighbours[self.cfg.match_window:]
                if not neighbours:
                    break
            matches = self._match_neighbours(neighbours, kf)
            inliers, disowned = self._pnp(seg.map, kf, neighbours, matches, self.cfg.pnp_px)
            if inliers is None and status == 'registered' and self.cfg.retry_pnp_px > 0.0 and \
                    len(ids) >= self.cfg.retry_min_keyframes:
                inliers, disowned = self._pnp(seg.map, kf, neighbours, matches,
                                              self.cfg.retry_pnp_px)
            jump = self._fooled(seg.map, kf, disowned) if inliers is not None else None
            if jump is not None:
                why = jump
                continue
            if inliers is not None:
                self._failures = 0
                seg.map.keyframes[kf.kf_id] = kf
                for lm_id, j in inliers:
                    seg.map.observe(lm_id, kf.kf_id, kf.features.points_px[j], j)
                guided = local_map.search(seg.map, self.K, kf, (self.camera.width,
                                                                self.camera.height),
                                          self.cfg.local_cfg)
                added = sum(self._triangulate(seg.map, n, kf, matches[n.kf_id])
                            for n in neighbours[:self.cfg.match_window])
                sfm_vertices.link(seg.map, self.K, kf, neighbours[:self.cfg.match_window],
                                  self.cfg.twoview_cfg, self.cfg.vertex_cfg)
                refined = self._refiner.refine(seg.map, kf)
                seg.graph.update(seg.map)
                return status, (f'{len(inliers)} PnP inliers, {guided} more from the local map, '
                                f'{added} new landmarks, {refined} observations refined')
        if len(seg.map.keyframes) == 2:
            return self._restart(seg, kf)
        self._failures += 1
        if self._failures < self.cfg.max_failures:
            return 'rejected', (f'keyframe {kf.kf_id} could not be registered or '
                                f'relocalised{why}: dropped ({self._failures} in a row)')
        self._failures = 0
        self.segments.append(self._new_segment())
        self.current.pending.append(kf)
        return 'new_segment', (f'keyframe {kf.kf_id} could not be registered or relocalised{why}: '
                               f'segment {len(self.segments) - 2} kept, new segment started')

    def _fooled(self, m: sfm_map.SfmMap, kf: sfm_map.MapKeyframe,
                disowned: str | None) -> str | None:
        """Why ``kf``'s new pose looks like a repeated texture's (None: it does not)."""
        off = self._off_track(m, kf)
        if off is not None:
            return off
        ids = sorted(m.keyframes)
        if len(ids) < 2 or self.cfg.max_velocity_change <= 0.0:
            return disowned
        path = np.array([m.keyframes[i].T_world_cam[:3, 3] for i in ids])
        steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
        return aliasing.velocity_reason(
            np.vstack([path[-2:], kf.T_world_cam[:3, 3]]),
            np.array([m.keyframes[ids[-2]].stamp_ns, m.keyframes[ids[-1]].stamp_ns,
                      kf.stamp_ns], np.int64), self.cfg.max_velocity_change,
            self.cfg.motion_check_s, self.cfg.slow_step_share * float(np.median(steps))) \
            or disowned

    def _off_track(self, m: sfm_map.SfmMap, kf: sfm_map.MapKeyframe) -> str | None:
        """Why ``kf``'s new pose goes elsewhere than the selector tracked (None: it does not,
        or there is no tracked step from a keyframe of the map)."""
        step = self._steps.get(kf.stamp_ns)
        if step is None or self.cfg.max_tracked_angle_deg >= 180.0:
            return None
        recent = [m.keyframes[i] for i in sorted(m.keyframes)[-self.cfg.relocalise_window:]]
        by_stamp = {k.stamp_ns: k for k in recent}
        while step.ref_stamp_ns not in by_stamp:  # its reference was dropped: bridge it
            earlier = self._steps.get(step.ref_stamp_ns)
            if earlier is None:
                return None
            step = keyframes.chain(earlier, step)
        angle = aliasing.step_angle_deg(by_stamp[step.ref_stamp_ns].T_world_cam, kf.T_world_cam,
                                        step.centre)
        if angle <= self.cfg.max_tracked_angle_deg:
            return None
        return (f' (its step points {angle:.0f} degrees away from the tracked motion: '
                'repeated texture matched one period off?)')

    def _restart(self, seg: Segment, kf: sfm_map.MapKeyframe) -> tuple[str, str]:
        """
        The keyframe after an initial pair does not register: the pair is too weak to carry a
        map (kept, it hangs on by few points at its own scale), so start again from its newer
        keyframe and ``kf``.
        """
        newer = seg.map.keyframes[max(seg.map.keyframes)]
        newer.T_world_cam, newer.landmark_of[:] = np.eye(4), -1
        if newer.vertices is not None:
            newer.vertices.landmark_of[:] = -1
        fresh = self._new_segment()
        fresh.pending = [newer]
        self.segments[-1] = fresh
        status, msg = self._try_initialise(fresh, kf)
        return status, f'initial pair dropped ({kf.kf_id} did not register on it); {msg}'

    def _match_neighbours(self, neighbours: list[sfm_map.MapKeyframe],
                          kf: sfm_map.MapKeyframe) -> dict[int, npt.NDArray[np.int64]]:
        """
        Verified matches of ``kf`` with each neighbour, newest first; with
        ``match_unclaimed_only`` a keypoint of ``kf`` matched by a newer neighbour is not looked
        for again (half the matching cost, somewhat less accurate).
        """
        free = np.ones(len(kf.features.points_px), bool)
        out = {}
        kf_index = feat.Index(kf.features.descriptors, self.cfg.feature_cfg)
        for n in neighbours:
            subset = np.flatnonzero(free) if self.cfg.match_unclaimed_only else None
            out[n.kf_id] = pairs = self._verified(n.features, kf.features, subset, kf_index)
            free[pairs[:, 1]] = False
        return out

    def _pnp(self, m: sfm_map.SfmMap, kf: sfm_map.MapKeyframe,
             neighbours: list[sfm_map.MapKeyframe],
             matches: dict[int, npt.NDArray[np.int64]], px: float
             ) -> tuple[list[tuple[int, int]] | None, str | None]:
        """PnP inliers within ``px`` as (landmark, keypoint) pairs (None: too few), and why the
        structure off the dominant plane disowns the pose (None: it does not)."""
        corr: dict[int, int] = {}  # keypoint of kf -> landmark
        claimed: set[int] = set()
        for n in neighbours:
            pairs = matches[n.kf_id].reshape(-1, 2)
            for lm_id, j in zip(n.landmark_of[pairs[:, 0]].tolist(), pairs[:, 1].tolist()):
                if lm_id >= 0 and j not in corr and lm_id not in claimed:
                    corr[j] = lm_id
                    claimed.add(lm_id)
        if len(corr) < self.cfg.min_pnp_inliers:
            return None, None
        kps = np.array(list(corr), np.int64)
        lms = [corr[int(j)] for j in kps]
        obj = np.array([m.landmarks[i].point_world for i in lms])
        img = kf.features.points_px[kps]
        cv2.setRNGSeed(int(self._rng.integers(2**31 - 1)))
        ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, self.K, None, iterationsCount=200,
                                                 reprojectionError=px,
                                                 confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
        if not ok or inl is None or len(inl) < self.cfg.min_pnp_inliers:
            return None, None
        inl = inl.ravel()
        _, rvec, tvec = cv2.solvePnP(obj[inl], img[inl], self.K, None, rvec, tvec, True,
                                     cv2.SOLVEPNP_ITERATIVE)
        disowned = None
        if self.cfg.min_off_plane_support > 0.0:  # loose: off-plane points are less accurate
            err = np.linalg.norm(cv2.projectPoints(obj, rvec, tvec, self.K, None)[0][:, 0] - img,
                                 axis=1)
            disowned = aliasing.off_plane_reason(
                obj, np.flatnonzero(err < self.cfg.plane_check_px), self.cfg.plane_tol,
                self.cfg.min_off_plane, self.cfg.min_off_plane_support, self._rng)
        R = cv2.Rodrigues(rvec)[0]  # camera-from-world
        kf.T_world_cam = np.eye(4)
        kf.T_world_cam[:3, :3], kf.T_world_cam[:3, 3] = R.T, (-R.T @ tvec).ravel()
        return [(lms[i], int(kps[i])) for i in inl], disowned

    def _triangulate(self, m: sfm_map.SfmMap, a: sfm_map.MapKeyframe, b: sfm_map.MapKeyframe,
                     pairs: npt.NDArray[np.int64]) -> int:
        free = pairs[(a.landmark_of[pairs[:, 0]] < 0) & (b.landmark_of[pairs[:, 1]] < 0)] \
            if len(pairs) else pairs
        if len(free) == 0:
            return 0
        pts, ok = twoview.triangulate(self.K, a.T_world_cam, b.T_world_cam,
                                      a.features.points_px[free[:, 0]],
                                      b.features.points_px[free[:, 1]], self.cfg.twoview_cfg)
        self._add_points(m, a, b, free[ok], pts[ok])
        return int(ok.sum())


def _forgotten(f: feat.Features) -> feat.Features:
    """Empty copies of a keyframe's features (new arrays: a [:0] view would keep the buffer)."""
    d = f.descriptors
    return feat.Features(np.empty((0, 2)), np.empty((0, 2)), np.empty((0, *d.shape[1:]), d.dtype),
                         np.empty((0, 3), np.uint8))
