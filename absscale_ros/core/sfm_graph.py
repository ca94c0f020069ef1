"""
GTSAM bundle adjustment of one map segment: iSAM2 per keyframe, periodic batch LM.

A feature landmark seen by two keyframes only enters iSAM2 with its third view (unless the
newest keyframe has too few observations in without it): the two-view ones were most of the
variables iSAM2 re-eliminated per keyframe. They are re-triangulated on the poses iSAM2 moved,
and every batch adjusts them all.

After each batch iSAM2 starts again from the batch's estimate with only the newest ``window``
keyframes free: observations in older keyframes enter it (when a landmark they see is
re-observed) as one Gaussian prior on the point per landmark (its held views linearised), so an
update costs what the recent part of the map costs, not the whole map nor the tracks' length;
iSAM2 eliminates landmarks before poses. Batches come every ``batch_every`` keyframes, and less
often as the map grows (``batch_growth``).

Keys: camera of keyframe ``i`` is ``X(i)``, landmark ``j`` is ``L(j)`` (``pose_key``,
``point_key``: the only mapping from ids to keys). Measurements are undistorted pixels, so the
factors use ``Cal3_S2`` with the CameraInfo ``K``.
"""
from collections.abc import Callable
from dataclasses import dataclass
from itertools import islice

import gtsam
from gtsam.symbol_shorthand import L, X
import numpy as np
import numpy.typing as npt

from absscale_ros.core import sfm_map

FloatArray = npt.NDArray[np.float64]
Progress = Callable[[str, float], None]
# Live, a paused batch that keyframes were added during is adopted after this many
# Levenberg-Marquardt iterations (the first ones take most of the error out), not converged:
# the longer it runs, the more of the map moved on since it began.
MIN_BATCH_ITERATIONS = 3


@dataclass(frozen=True)
class GraphConfig:
    """Noise and schedule of the bundle adjustment."""

    sigma_px: float = 1.0  # measurement noise of a feature, px
    vertex_weight: float = 2.0  # cost weight of target-vertex observations: sigma / sqrt(w)
    huber_k: float = 1.345  # Huber threshold in sigmas
    batch_every: int = 10  # full Levenberg-Marquardt at least this many keyframes apart
    batch_growth: float = 0.25  # ... and only once the segment grew by this share since the last
    batch_iterations: int = 25
    # A periodic batch stops once an iteration lowers the cost by less than this share (GTSAM's
    # default 1e-5; ``finish`` always converges to that). Huber re-weighting makes a long tail
    # of tiny steps: 1e-3 took 3 iterations instead of 14 on outdoor 51 (0.89 s CPU instead of
    # 2.99, centres within 0.0005 % of the path) and the SfM's time x0.74-0.78 on the outdoor
    # tuning bags, but the final camera RMSE was 0.1-12 % higher on all 6 samples and tuning
    # bags (other culls after the looser batches), so the default stays converged.
    batch_rel_tol: float = 1e-5
    cull_px: float = 3.0  # observations further than this after a batch are dropped
    window: int = 10  # keyframes iSAM2 may move between batches; older ones are held
    # A feature landmark enters iSAM2 once this many keyframes see it (4, not 3: iSAM2's
    # update ~30 % cheaper, the fewer-view ones re-triangulated and taken by every batch), ...
    incremental_min_views: int = 4
    incremental_min_obs: int = 300  # ... or sooner while the newest keyframe has fewer in it
    relinearize_threshold: float = 0.01  # iSAM2 relinearises a variable that moved this far
    relinearize_skip: int = 10  # ... checking every this many updates
    # A landmark's views in held keyframes enter iSAM2 as one Gaussian prior on the point
    # (False: one projection factor each). Tracks grow to ~20 views at 200+ keyframes of the
    # 60 s bag, and iSAM2 re-eliminated all of a re-observed landmark's factors.
    held_prior: bool = True

    def __post_init__(self) -> None:
        if min(self.sigma_px, self.vertex_weight, self.huber_k, self.cull_px) <= 0.0 or \
                self.batch_every < 1 or self.batch_iterations < 1 or self.window < 2 or \
                not 0.0 < self.batch_rel_tol < 1.0 or \
                self.batch_growth < 0.0 or self.incremental_min_views < 2 or \
                self.incremental_min_obs < 0 or self.relinearize_threshold < 0.0 or \
                self.relinearize_skip < 1:
            raise ValueError(f'bad graph config {self}')


_X, _L = X(0), L(0)  # symbol keys are chr << 56 | index: ids map to keys by one OR


def pose_key(kf_id: int) -> int:
    return _X | kf_id


def point_key(lm_id: int) -> int:
    return _L | lm_id


class SegmentGraph:
    """Incremental smoother of one ``SfmMap``; the map holds the estimate after each call."""

    def __init__(self, K: FloatArray, cfg: GraphConfig) -> None:
        self._cfg = cfg
        self._cal = gtsam.Cal3_S2(K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2])
        huber = gtsam.noiseModel.mEstimator.Huber.Create(cfg.huber_k)
        self._noise = gtsam.noiseModel.Robust.Create(
            huber, gtsam.noiseModel.Isotropic.Sigma(2, cfg.sigma_px))
        self._vertex_sigma = cfg.sigma_px / np.sqrt(cfg.vertex_weight)
        self._vertex_noise = gtsam.noiseModel.Robust.Create(
            huber, gtsam.noiseModel.Isotropic.Sigma(2, self._vertex_sigma))
        self._last_batch_size = 0
        self._paused: _PausedBatch | None = None  # live: a batch keyframes may come between
        self._reset()

    def _reset(self, free_from: int = -1) -> None:
        """Empty iSAM2; keyframes with ids below ``free_from`` are held: fixed cameras."""
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self._cfg.relinearize_threshold)
        params.relinearizeSkip = self._cfg.relinearize_skip
        self._isam = gtsam.ISAM2(params)
        self._factors: set[tuple[int, int]] = set()  # (kf_id, lm_id) already in iSAM2
        self._n_in: dict[int, int] = {}  # landmark -> its views looked at (see _add_landmark)
        self._keys: set[int] = set()
        self._pose_keys: list[int] = []  # the pose keys among them (iSAM2's ordering groups)
        self._free_from = free_from
        self._held_cams: dict[int, gtsam.PinholeCameraCal3_S2] = {}
        self._gauge_done = free_from >= 0  # held keyframes fix the gauge
        self._all_pending = True  # next _new_terms looks at every landmark, not just dirty ones
        self._held_views: list[tuple[int, int]] = []  # (lm_id, kf_id) for ``_add_held``

    def release(self) -> None:
        """Let go of the iSAM2 state (a finished segment); ``batch`` still works after."""
        self._paused = None
        self._reset()

    @property
    def observations_in(self) -> int:
        """(keyframe, landmark) observations iSAM2 holds since its last restart."""
        return len(self._factors)

    @property
    def poses_in(self) -> int:
        """Keyframe poses iSAM2 holds since its last restart (held ones are not variables)."""
        return len(self._pose_keys)

    @property
    def held_before(self) -> int:
        """Keyframes with ids below this one are held fixed in iSAM2 (-1: none)."""
        return self._free_from

    def batch_due(self, keyframes: int) -> bool:
        """Whether a segment of ``keyframes`` keyframes is due a full batch adjustment."""
        since = keyframes - self._last_batch_size
        return since >= max(self._cfg.batch_every, self._cfg.batch_growth * self._last_batch_size)

    def _noise_of(self, lm: sfm_map.Landmark) -> gtsam.noiseModel.Base:
        return self._vertex_noise if lm.label is not None else self._noise

    def _held_factor(self, m: sfm_map.SfmMap, lm: sfm_map.Landmark, kf_id: int,
                     lm_id: int) -> gtsam.NonlinearFactor:
        """
        Projection into a held keyframe's fixed camera. Held poses used to be variables pinned
        by a tight prior: long tracks pulled every pose of the segment into iSAM2 that way, and
        an update's cost grew with the map (40 ms CPU at 7 keyframes, 775 at 72).
        """
        cam = self._held_cams.get(kf_id)
        if cam is None:
            cam = self._held_cams[kf_id] = gtsam.PinholeCameraCal3_S2(
                gtsam.Pose3(m.keyframes[kf_id].T_world_cam), self._cal)
        return gtsam.TriangulationFactorCal3_S2(cam, lm.obs_px[kf_id], self._noise_of(lm),
                                                point_key(lm_id))

    def _add_held(self, m: sfm_map.SfmMap, graph: gtsam.NonlinearFactorGraph) -> None:
        """
        The held views ``_add_landmark`` collected, one factor per landmark: a Gaussian prior
        on the point, their Huber-weighted projections linearised at its estimate (a landmark
        with one usable held view keeps its projection factor).
        """
        views, self._held_views = self._held_views, []
        if not views:
            return
        lms, kfs = np.array(views, np.int64).T
        ids, inv = np.unique(lms, return_inverse=True)
        landmarks, K = m.landmarks, self._cal.K()
        pts = np.array([landmarks[i].point_world for i in ids.tolist()])
        uv = np.array([landmarks[i].obs_px[k] for i, k in views])
        sigma = np.array([self._vertex_sigma if landmarks[i].label is not None
                          else self._cfg.sigma_px
                          for i in ids.tolist()])[inv]
        kf_u, kf_inv = np.unique(kfs, return_inverse=True)
        T = np.array([m.keyframes[k].T_world_cam for k in kf_u.tolist()])[kf_inv]
        R = np.transpose(T[:, :3, :3], (0, 2, 1))  # camera from world
        pc = np.einsum('nij,nj->ni', R, pts[inv] - T[:, :3, 3])
        x, y, z = pc.T
        ok = z > 1e-9
        z = np.where(ok, z, 1.0)
        fx, fy, sk = K[0, 0], K[1, 1], K[0, 1]
        r = np.stack([(fx * x + sk * y) / z + K[0, 2], fy * y / z + K[1, 2]], 1) - uv
        dpi = np.zeros((len(views), 2, 3))
        dpi[:, 0, 0], dpi[:, 0, 1], dpi[:, 0, 2] = fx / z, sk / z, -(fx * x + sk * y) / z**2
        dpi[:, 1, 1], dpi[:, 1, 2] = fy / z, -fy * y / z**2
        J = dpi @ R / sigma[:, None, None]
        rw = r / sigma[:, None]
        e = np.linalg.norm(rw, axis=1)
        w = np.where(ok, np.minimum(1.0, self._cfg.huber_k / np.maximum(e, 1e-12)), 0.0)
        info = np.zeros((len(ids), 3, 3))
        grad = np.zeros((len(ids), 3))
        np.add.at(info, inv, w[:, None, None] * np.transpose(J, (0, 2, 1)) @ J)
        np.add.at(grad, inv, w[:, None] * np.einsum('nji,nj->ni', J, rw))
        n_views = np.bincount(inv, weights=ok.astype(float), minlength=len(ids))
        eig = np.linalg.eigvalsh(info)
        good = (n_views >= 2) & (eig[:, 0] > 1e-9 * np.maximum(eig[:, 2], 1e-300))
        sel = np.flatnonzero(good)
        means = pts[sel] - np.linalg.solve(info[sel], grad[sel, :, None])[:, :, 0]
        for n, mean in zip(sel.tolist(), means):
            graph.add(gtsam.PriorFactorPoint3(_L | int(ids[n]), mean,
                                              gtsam.noiseModel.Gaussian.Information(info[n])))
        for (lm_id, kf_id), single in zip(views, (~good[inv]).tolist()):
            if single:
                graph.add(self._held_factor(m, landmarks[lm_id], kf_id, lm_id))

    def _insert_pose(self, m: sfm_map.SfmMap, kf_id: int, values: gtsam.Values) -> None:
        self._keys.add(pose_key(kf_id))
        self._pose_keys.append(pose_key(kf_id))
        values.insert(pose_key(kf_id), gtsam.Pose3(m.keyframes[kf_id].T_world_cam))

    def _gauge(self, m: sfm_map.SfmMap, graph: gtsam.NonlinearFactorGraph) -> None:
        """Fix the first pose and the distance to the second (7 gauge freedoms of monocular)."""
        ids = sorted(m.keyframes)[:2]
        a, b = m.keyframes[ids[0]].T_world_cam, m.keyframes[ids[1]].T_world_cam
        graph.add(gtsam.PriorFactorPose3(pose_key(ids[0]), gtsam.Pose3(a),
                                         gtsam.noiseModel.Isotropic.Sigma(6, 1e-4)))
        graph.add(gtsam.RangeFactorPose3(pose_key(ids[0]), pose_key(ids[1]),
                                         float(np.linalg.norm(b[:3, 3] - a[:3, 3])),
                                         gtsam.noiseModel.Isotropic.Sigma(1, 1e-4)))

    def _new_terms(self, m: sfm_map.SfmMap, min_views: int = 2,
                   min_obs: int = 0) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
        """
        Factors and values of the map not yet in the graph: of landmarks seen by at least
        ``min_views`` keyframes (target vertices: 2), and of fewer-view ones seen by the newest
        keyframe while it has fewer than ``min_obs`` observations in. A landmark left out now
        is looked at again when ``SfmMap.observe`` gives it another view.
        """
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if not self._gauge_done:
            self._gauge(m, graph)
            self._gauge_done = True
        # Only landmarks observed since the last call can bring new factors (O(new), not O(map)).
        if self._all_pending and self._free_from >= 0:  # the landmarks of the free keyframes
            todo = _seen_by(m, [k for k in m.keyframes if k >= self._free_from])
        else:
            todo = list(m.landmarks) if self._all_pending else \
                [i for i in m.dirty if i in m.landmarks]
        self._all_pending = False
        m.dirty.clear()
        newest, weak, landmarks = max(m.keyframes, default=-1), [], m.landmarks
        for lm_id in todo:
            lm = landmarks[lm_id]
            if len(lm.obs_px) < (2 if lm.label is not None else min_views):
                if len(lm.obs_px) >= 2 and newest in lm.obs_px:
                    weak.append(lm_id)
                continue
            self._add_landmark(m, lm_id, lm, graph, values)
        have = sum((newest, lm_id) in self._factors for lm_id in todo)
        for lm_id in weak[:max(0, min_obs - have)]:
            self._add_landmark(m, lm_id, landmarks[lm_id], graph, values)
        self._add_held(m, graph)
        return graph, values

    def _add_landmark(self, m: sfm_map.SfmMap, lm_id: int, lm: sfm_map.Landmark,
                      graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
        # Called for ~1000 landmarks an update, most with one new view among many: the keys and
        # noise once per landmark, the factor built inline (the helper calls cost ~1/3 of it).
        # Its views in iSAM2 are the first ``n_in`` it got (a dict keeps insertion order):
        # only the later ones are looked at, not the whole track (~20 views at 200 keyframes).
        factors, keys, free_from = self._factors, self._keys, self._free_from
        obs, n_in = lm.obs_px, self._n_in.get(lm_id, 0)
        if len(obs) <= n_in:
            return
        self._n_in[lm_id] = len(obs)
        noise, lm_key = self._noise_of(lm), _L | lm_id
        for kf_id, uv in islice(obs.items(), n_in, None):
            if (kf_id, lm_id) in factors:
                continue
            factors.add((kf_id, lm_id))
            if kf_id < free_from:  # held: a factor on the point alone
                if self._cfg.held_prior:
                    self._held_views.append((lm_id, kf_id))
                else:
                    graph.add(self._held_factor(m, lm, kf_id, lm_id))
                continue
            graph.add(gtsam.GenericProjectionFactorCal3_S2(uv, noise, _X | kf_id, lm_key,
                                                           self._cal))
            if (_X | kf_id) not in keys:
                self._insert_pose(m, kf_id, values)
        if lm_key not in keys:
            keys.add(lm_key)
            values.insert(lm_key, gtsam.Point3(*lm.point_world))

    def _poses_last(self) -> gtsam.KeyGroupMap:
        """
        iSAM2's ordering constraint: every pose after every landmark. By default it puts the
        keys of the new factors last, i.e. the ~1000 landmarks the newest keyframe sees after
        the older free poses: each such pose, eliminated first, tied all its landmarks into one
        dense clique (the update cost 340-590 ms CPU at 230 keyframes on the 60 s bag; 40-90
        with this and ``held_prior``). Landmarks first is bundle adjustment's Schur order.
        """
        groups = gtsam.KeyGroupMap()
        for k in self._pose_keys:
            groups.insert2(k, 1)
        return groups

    def _write_back(self, m: sfm_map.SfmMap, est: gtsam.Values) -> None:
        for kf_id, kf in m.keyframes.items():
            if est.exists(pose_key(kf_id)):
                kf.T_world_cam = est.atPose3(pose_key(kf_id)).matrix()
        # Every point at once (extractPoint3 lists them in key order, i.e. by landmark id).
        keys = np.array(est.keys(), np.uint64)  # a symbol key is chr << 56 | index
        ids = np.sort(keys[(keys >> np.uint64(56)) == ord('l')] & np.uint64(2**56 - 1))
        for lm_id, p in zip(ids.tolist(), gtsam.utilities.extractPoint3(est)):
            lm = m.landmarks.get(lm_id)
            if lm is not None:
                lm.point_world = p

    def update(self, m: sfm_map.SfmMap, fallback: bool = True) -> None:
        """
        Add the map's new observations to iSAM2, update, write the estimate into ``m``.
        Once ``2 * window`` keyframes are free, iSAM2 starts again from the current estimate
        with only the newest ``window`` free (between batches, which come rarer as the map
        grows, its cost would otherwise grow with them).

        :param fallback: on an ill-conditioned iSAM2 step, run ``batch`` instead of raising.
        """
        ids = sorted(m.keyframes)
        if fallback and len(ids) > 2 * self._cfg.window and \
                ids[-2 * self._cfg.window] >= max(self._free_from, 0):
            m.dirty.clear()  # the restart looks at every landmark of the free keyframes
            self._reset(ids[-self._cfg.window])
        # Two-view feature landmarks wait for a third view (a batch takes them all): they
        # were most of iSAM2's re-eliminated variables, and the cost, for little constraint.
        graph, values = self._new_terms(m, min(self._cfg.incremental_min_views, len(ids)),
                                        self._cfg.incremental_min_obs)
        if graph.size() == 0:
            return
        try:
            self._isam.update(graph, values, [], self._poses_last())
        except RuntimeError:  # gtsam IndeterminantLinearSystem: damped batch LM copes with it
            if not fallback:
                raise
            self.batch(m)
            return
        self._write_back(m, self._isam.calculateEstimate())
        # The newest window: they moved most, and matching and the local map look only there.
        self._retriangulate(m, [k for k in ids[-self._cfg.window:] if k >= self._free_from])

    def _retriangulate(self, m: sfm_map.SfmMap, kf_ids: list[int]) -> None:
        """
        Move the two-view landmarks of ``kf_ids`` left out of iSAM2 onto their poses as iSAM2
        just moved them (linear triangulation, all at once), so they stay consistent for PnP.
        """
        keys, landmarks = self._keys, m.landmarks
        lms = [lm for lm in (landmarks[i] for i in _seen_by(m, kf_ids) if _L | i not in keys)
               if len(lm.obs_px) == 2]
        if not lms:
            return
        # (N, 2) keyframe ids and (N, 2, 2) px, flattened in one pass (no nested lists)
        kfs = np.fromiter((k for lm in lms for k in lm.obs_px), np.int64, 2 * len(lms))
        kfs = kfs.reshape(-1, 2)
        uv = np.concatenate([x for lm in lms for x in lm.obs_px.values()]).reshape(-1, 2, 2)
        ks = np.unique(kfs)
        K = np.array(self._cal.K())
        P = np.array([K @ np.linalg.inv(m.keyframes[int(k)].T_world_cam)[:3] for k in ks])
        P = P[np.searchsorted(ks, kfs)]  # (N, 2, 3, 4)
        A = (uv[..., None] * P[:, :, 2:3] - P[:, :, :2]).reshape(len(lms), 4, 4)
        X = np.linalg.svd(A)[2][:, -1]  # DLT: the null vector of each landmark's 4x4 system
        with np.errstate(divide='ignore', invalid='ignore'):
            pts = X[:, :3] / X[:, 3:]
        for n in np.flatnonzero(np.all(np.isfinite(pts), axis=1)).tolist():
            lms[n].point_world = pts[n]

    def batch(self, m: sfm_map.SfmMap, progress: Progress | None = None,
              stop: Callable[[], bool] | None = None, converged: bool = False) -> int:
        """
        Levenberg-Marquardt over the whole segment, cull outliers, restart iSAM2 from the result.

        :param stop: live: asked between the steps (the problem built, each iteration) whether
            a keyframe waits; if so the batch pauses, iSAM2 goes on placing keyframes, and the
            next call resumes it (``_PausedBatch``). None: all at once.
        :param converged: to GTSAM's default tolerance, not ``batch_rel_tol`` (the final one).
        :returns: number of landmarks culled (0 while paused).
        """
        if stop is not None:
            return self._batch_in_steps(m, progress, stop)
        self._paused = None  # a paused one would be older than this
        self._reset()
        graph, values = self._new_terms(m)
        opt = gtsam.LevenbergMarquardtOptimizer(graph, values, self._lm_params(converged))
        if progress is not None:
            progress('batch start', graph.error(values))
        result = opt.optimize()
        if progress is not None:
            progress('batch done', graph.error(result))
        return self._adopt(m, result, len(m.keyframes))

    def _adopt(self, m: sfm_map.SfmMap, result: gtsam.Values, size: int) -> int:
        """The batch estimate into ``m``, outliers culled, iSAM2 restarted from it; ``size``:
        the keyframes the batch adjusted (the next is due once the map grew enough from it)."""
        self._write_back(m, result)
        culled = m.cull(np.array(self._cal.K()), self._cfg.cull_px)
        ids = sorted(m.keyframes)
        if size >= self._cfg.batch_every:  # the two-view start's own batch does not count
            self._last_batch_size = size
        self._reset(ids[-self._cfg.window] if len(ids) > self._cfg.window else -1)
        try:
            self.update(m, fallback=False)
        except RuntimeError:
            # Ill-posed with the older keyframes held (60 s bag, live: the held views tied the
            # free ones too weakly), so every keyframe free, the gauge fixed by priors; if that
            # fails too, keep the LM estimate: the next keyframe restarts iSAM2 (or falls back
            # to a batch in its update).
            self._reset()
            try:
                self.update(m, fallback=False)
            except RuntimeError:
                self._reset(self._free_from)
        return culled

    def _lm_params(self, converged: bool = False) -> gtsam.LevenbergMarquardtParams:
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(self._cfg.batch_iterations)
        if not converged:
            params.setRelativeErrorTol(self._cfg.batch_rel_tol)
        return params

    def _batch_in_steps(self, m: sfm_map.SfmMap, progress: Progress | None,
                        stop: Callable[[], bool]) -> int:
        """
        ``batch`` that pauses for a waiting keyframe: a batch costs 0.5-1.6 s on the 60 s bag,
        a keyframe's update 0.2-0.5, and one that waited behind it was skipped for the next.
        The problem is the map as the batch began (a copy), so iSAM2 places keyframes in the
        pauses as if no batch were running; the result is adopted once it converged (or, if
        keyframes came meanwhile, after ``MIN_BATCH_ITERATIONS``), the keyframes and landmarks
        added meanwhile carried along by the newest batched keyframe's move.
        """
        if self._paused is None:
            dirty = set(m.dirty)  # the batch's own graph marks every landmark looked at
            builder = SegmentGraph(np.array(self._cal.K()), self._cfg)
            graph, values = builder._new_terms(m)
            m.dirty.update(dirty)
            self._paused = _PausedBatch(graph, values, self._lm_params(), max(m.keyframes),
                                        len(m.keyframes))
            if progress is not None:
                progress('batch start', graph.error(values))
        b = self._paused
        while not b.done and not (b.opt.iterations() >= MIN_BATCH_ITERATIONS and
                                  max(m.keyframes) > b.newest):
            if stop():
                return 0
            b.iterate()
        if stop():  # adopting costs about an iteration: after the keyframe
            return 0
        self._paused = None
        if progress is not None:
            progress('batch done', b.opt.error())
        return self._adopt(m, b.carried(m), b.size)


class _PausedBatch:
    """A batch Levenberg-Marquardt run one iteration at a time (``SegmentGraph.batch``)."""

    def __init__(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                 params: gtsam.LevenbergMarquardtParams, newest: int, size: int) -> None:
        self.opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
        self.newest, self.size, self._max = newest, size, params.getMaxIterations()
        self.error = self.opt.error()
        self._tol = (params.getRelativeErrorTol(), params.getAbsoluteErrorTol(),
                     params.getErrorTol())
        self.done = self.error <= self._tol[2]

    def iterate(self) -> None:
        """One iteration; ``done`` as GTSAM's ``optimize()`` would stop after it."""
        before = self.error
        self.opt.iterate()
        self.error = self.opt.error()
        self.done = self.opt.iterations() >= self._max or not np.isfinite(self.error) or \
            gtsam.checkConvergence(*self._tol, before, self.error)

    def carried(self, m: sfm_map.SfmMap) -> gtsam.Values:
        """
        The result, with the keyframes and landmarks of ``m`` added after the batch began
        moved as the newest batched keyframe moved (iSAM2 placed them against the old poses).
        """
        est = gtsam.Values(self.opt.values())
        if self.newest not in m.keyframes:
            return est
        T_new = est.atPose3(pose_key(self.newest)).matrix()
        C = T_new @ np.linalg.inv(m.keyframes[self.newest].T_world_cam)
        for kf_id, kf in m.keyframes.items():
            if kf_id > self.newest:
                est.insert(pose_key(kf_id), gtsam.Pose3(C @ kf.T_world_cam))
        for lm_id, lm in m.landmarks.items():  # new (the batch took all of 2 views or more)
            if not est.exists(point_key(lm_id)):
                est.insert(point_key(lm_id), gtsam.Point3(C[:3, :3] @ lm.point_world + C[:3, 3]))
        return est


def _seen_by(m: sfm_map.SfmMap, kf_ids: list[int]) -> list[int]:
    """Ids (sorted) of the landmarks of ``m`` that keyframes ``kf_ids`` see: O(their features)."""
    seen: set[int] = set()
    for k in kf_ids:
        kf = m.keyframes[k]
        seen.update(kf.landmark_of[kf.landmark_of >= 0].tolist())
        if kf.vertices is not None:
            seen.update(kf.vertices.landmark_of[kf.vertices.landmark_of >= 0].tolist())
    return sorted(filter(m.landmarks.__contains__, seen))
