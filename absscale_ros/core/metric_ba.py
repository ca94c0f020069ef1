"""
Known-length factors inside the bundle adjustment: issue #7's alternative to a fitted factor.

The map's target-vertex landmarks are matched to the target model by shape (``scale``'s
assignment); each model edge or diagonal between two matched vertices becomes a GTSAM
``RangeFactor3`` of its true length in metres, and the whole segment is adjusted again with its
projection factors and only the first camera's pose held. The lengths then set the scale inside
the graph, where the reprojections can pull against them, instead of being fitted afterwards.
The factor reported is the scale between the map's and the metric camera centres (Umeyama).
"""
from dataclasses import dataclass

import gtsam
import numpy as np
import numpy.typing as npt

from absscale_ros.core import align, scale, sfm_graph, sfm_map
from absscale_ros.core.errors import DegenerateGeometryError, NotObservableError

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class LengthFactorConfig:
    """Noise of the known lengths and of the re-adjustment."""

    length_sigma_m: float = 0.001  # target manufacturing / printing tolerance, 1 sigma
    sigma_px: float = 1.0  # feature measurement noise, px (as the SfM's graph)
    vertex_weight: float = 2.0  # cost weight of target-vertex observations
    huber_k: float = 1.345
    iterations: int = 50

    def __post_init__(self) -> None:
        if min(self.length_sigma_m, self.sigma_px, self.vertex_weight, self.huber_k) <= 0.0:
            raise ValueError(f'bad length factor config {self}')


@dataclass(frozen=True)
class Constraint:
    """Landmarks ``a`` and ``b`` are ``length_m`` apart on the target."""

    a: int
    b: int
    length_m: float


def constraints(m: sfm_map.SfmMap, obj: scale.ObjectVertices, lm_ids: list[int],
                cfg: scale.ScaleConfig) -> list[Constraint]:
    """
    Known lengths between the usable vertex landmarks of one object.

    :param obj: the object's vertices as the scale stage sees them (same order as ``lm_ids``).
    :param lm_ids: the landmark id of each of ``obj.points``.
    :raises NotObservableError: fewer than ``cfg.min_vertices`` usable or no model fits.
    """
    keep = np.flatnonzero(scale.usable(obj.n_obs, obj.angles_deg, cfg))
    if len(keep) < cfg.min_vertices:
        raise NotObservableError(f'{len(keep)} well-observed vertices < {cfg.min_vertices}')
    pts = np.asarray(obj.points, float)[keep]
    try:
        model = scale.which_model(pts, obj, cfg)
        kept, _ = scale.drop_outlier_vertex(pts, model, cfg)  # as the fitted factor does
        keep = keep[kept]
        ids, _ = scale.assign_to_model(pts[kept], model, cfg)
    except DegenerateGeometryError as err:
        raise NotObservableError(str(err)) from err
    out = []
    for i in range(len(keep)):
        for j in range(i + 1, len(keep)):
            out.append(Constraint(lm_ids[keep[i]], lm_ids[keep[j]],
                                  float(np.linalg.norm(model[ids[i]] - model[ids[j]]))))
    return out


def adjust(m: sfm_map.SfmMap, K: FloatArray, known: list[Constraint], factor0: float,
           cfg: LengthFactorConfig) -> tuple[float, FloatArray]:
    """
    Re-adjust map segment ``m`` with ``known`` lengths; return (factor, metric camera centres).

    :param K: (3, 3) intrinsics of the undistorted observations.
    :param factor0: a first metres-per-unit guess (the fitted factor) to start from.
    :returns: metres per map unit, and (N, 3) camera centres in metres (keyframe id order).
    """
    if not known:
        raise NotObservableError('no known lengths')
    cal = gtsam.Cal3_S2(K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2])
    huber = gtsam.noiseModel.mEstimator.Huber.Create(cfg.huber_k)
    noise = gtsam.noiseModel.Robust.Create(huber,
                                           gtsam.noiseModel.Isotropic.Sigma(2, cfg.sigma_px))
    vertex_noise = gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Isotropic.Sigma(
        2, cfg.sigma_px / np.sqrt(cfg.vertex_weight)))
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    kf_ids = sorted(m.keyframes)
    for kf_id in kf_ids:
        T = m.keyframes[kf_id].T_world_cam.copy()
        T[:3, 3] *= factor0
        values.insert(sfm_graph.pose_key(kf_id), gtsam.Pose3(T))
    for lm_id, lm in m.landmarks.items():
        obs = {k: p for k, p in lm.obs_px.items() if k in m.keyframes}
        if len(obs) < 2:
            continue
        values.insert(sfm_graph.point_key(lm_id), np.asarray(lm.point_world) * factor0)
        for kf_id, px in obs.items():
            graph.add(gtsam.GenericProjectionFactorCal3_S2(
                np.asarray(px, float), vertex_noise if lm.label is not None else noise,
                sfm_graph.pose_key(kf_id), sfm_graph.point_key(lm_id), cal))
    first = sfm_graph.pose_key(kf_ids[0])
    graph.add(gtsam.PriorFactorPose3(first, values.atPose3(first),
                                     gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    length_noise = gtsam.noiseModel.Isotropic.Sigma(1, cfg.length_sigma_m)
    for c in known:
        if not values.exists(sfm_graph.point_key(c.a)) or \
                not values.exists(sfm_graph.point_key(c.b)):
            continue
        graph.add(gtsam.RangeFactor3(sfm_graph.point_key(c.a), sfm_graph.point_key(c.b),
                                     c.length_m, length_noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(cfg.iterations)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    before = np.array([m.keyframes[k].T_world_cam[:3, 3] for k in kf_ids])
    after = np.array([result.atPose3(sfm_graph.pose_key(k)).translation() for k in kf_ids])
    factor = align.umeyama(before, after)[0] if len(kf_ids) >= 3 else factor0
    return float(factor), after
