"""
Metric scale from reconstructed calibration-object vertices (the paper's eq. 8-10, and better).

Pipeline per object: match the reconstructed vertices to the target model by shape (label
free, so a cyclic shift of sheet corners or a mislabelled cube vertex cannot bias the scale),
turn every vertex pair into a (measured, true) length, reject outlying vertices, and fit one
factor over all objects with its standard error. Below the observability gate no scale is
claimed (``NotObservableError``).
"""
from dataclasses import dataclass, field
from functools import lru_cache
from itertools import permutations

import numpy as np
import numpy.typing as npt

from absscale_ros.core import aliasing
from absscale_ros.core.errors import DegenerateGeometryError, NotObservableError

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ScaleConfig:
    """Thresholds of the scale stage (all in the config YAML of the scale node)."""

    min_keyframes: int = 8  # a reconstruction of fewer keyframes is too weak to scale from
    min_vertices: int = 3  # per object: fewer leave the model assignment ambiguous
    min_observations: int = 3  # keyframes that saw a vertex before it counts
    min_angle_deg: float = 3.0  # widest triangulation angle of a vertex before it counts
    max_shape_residual: float = 0.02  # RMS relative length misfit of the best assignment
    ambiguity_ratio: float = 3.0  # second-best assignment must misfit this many times more
    outlier_sigma: float = 3.5  # reject a vertex whose pairs deviate by this many MADs
    # Vertices of one object closer than this share of its median vertex distance are one
    # corner reconstructed twice (seen again after the camera walked round it): the one seen
    # under the widest angle stays. While an object has more vertices than its target has
    # corners, the closest two nearer than half its smallest corner distance are one too (0: off).
    duplicate_share: float = 0.05
    # Claim a scale only when sigma / factor is below this (0.004 in every shipped config: 0.4 %
    # of the factor; a config file that leaves it out gets the same gate).
    max_relative_sigma: float = 0.004
    confidence: float = 0.95  # of the reported interval
    # The vertex residuals only see noise at the target; the reconstruction's own scale drift
    # between the target and the rest of the scene adds this much (relative, 1 sigma; 0.003 as
    # in every shipped config: without it the interval is the target's alone, too narrow).
    drift_sigma_rel: float = 0.003
    # A keyframe path whose velocity changes by more than this times the speed within
    # ``path_jump_s`` has a link the SfM got wrong (a repeated texture matched a period off):
    # the map is bent there and no one factor scales it, so none is claimed (0: off).
    max_path_jump: float = 1.2
    path_jump_s: float = 1.0

    def __post_init__(self) -> None:
        if self.min_vertices < 2 or self.min_observations < 1:
            raise ValueError('min_vertices must be >= 2 and min_observations >= 1')
        if min(self.drift_sigma_rel, self.max_path_jump, self.path_jump_s,
               self.duplicate_share) < 0.0:
            raise ValueError('drift_sigma_rel, max_path_jump, path_jump_s and duplicate_share '
                             'must be >= 0')
        if not 0.0 < self.confidence < 1.0 or self.max_relative_sigma <= 0.0:
            raise ValueError('confidence must be in (0, 1) and max_relative_sigma > 0')


@dataclass(frozen=True, eq=False)
class ScaleEstimate:
    """
    Metres per reconstruction unit, with what it rests on.

    :param factor: metres per SfM unit.
    :param sigma: its standard error (same unit).
    :param interval: (low, high) confidence interval of ``factor``.
    :param measured: (E,) reconstructed lengths used, SfM units.
    :param true_m: (E,) their true lengths, m.
    :param residuals_m: (E,) ``factor * measured - true_m``, m.
    :param rejected: human-readable reasons for vertices or objects left out.
    """

    factor: float
    sigma: float
    interval: tuple[float, float]
    measured: FloatArray
    true_m: FloatArray
    residuals_m: FloatArray
    objects_used: int
    rejected: list[str] = field(default_factory=list)


def model_vertices_m(kind: str, size_m: tuple[float, ...]) -> FloatArray:
    """(K, 3) model vertices, m: a sheet's 4 corners in order, or a cube's 8 corners."""
    if kind == 'sheet':
        w, h = size_m[:2]
        return np.array([[0.0, 0.0, 0.0], [w, 0.0, 0.0], [w, h, 0.0], [0.0, h, 0.0]])
    if kind == 'cube':
        idx = np.arange(8)
        bits = np.stack([idx & 1, (idx >> 1) & 1, (idx >> 2) & 1], axis=1)
        return float(size_m[0]) * bits.astype(np.float64)
    raise ValueError(f'unknown target kind {kind!r}')


def _pair_index(n: int) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    i, j = np.triu_indices(n, k=1)
    return i.astype(np.int64), j.astype(np.int64)


@lru_cache(maxsize=16)
def _assignments(k: int, n: int) -> npt.NDArray[np.int64]:
    """
    Every ordered choice of ``n`` of ``k`` model vertices that gives the first model vertex to
    the first point (8!/8 = 5040 rows for a cube): the models (a rectangle, a cube) have a
    symmetry taking any vertex to any other, and symmetric assignments fit equally, at one
    scale, so these rows hold every misfit and scale there is, at an eighth of the cost.
    """
    rest = permutations(range(1, k), n - 1)
    return np.array([(0, *p) for p in rest], dtype=np.int64).reshape(-1, n)


def assign_to_model(points: FloatArray, model_m: FloatArray,
                    cfg: ScaleConfig) -> tuple[npt.NDArray[np.int64], float]:
    """
    Match reconstructed vertices to model vertices by shape alone.

    Every injective assignment is scored by how well one scale maps the model's pairwise
    distances onto the reconstructed ones (scale-free RMS relative misfit).

    :param points: (N, 3) reconstructed vertices of one object, SfM units, N >= 3.
    :param model_m: (K, 3) model vertices, m.
    :returns: (N,) model vertex index per point, and the misfit of that assignment.
    :raises DegenerateGeometryError: if the best assignment misfits or is ambiguous.
    """
    n = len(points)
    if n > len(model_m):  # e.g. one corner reconstructed twice
        raise DegenerateGeometryError(f'{n} vertices for a target that has {len(model_m)}')
    pi, pj = _pair_index(n)
    d = np.linalg.norm(points[pi] - points[pj], axis=1)
    if np.any(d <= 0.0) or not np.all(np.isfinite(d)):
        raise DegenerateGeometryError('coincident or non-finite vertices')
    perms = _assignments(len(model_m), n)
    model_pair_m = np.linalg.norm(model_m[:, None] - model_m[None, :], axis=2)
    model_d = model_pair_m[perms[:, pi], perms[:, pj]]
    s = (model_d @ d) / np.einsum('ij,ij->i', model_d, model_d)  # best scale per assignment
    misfit = np.sqrt(np.mean(((s[:, None] * model_d - d[None, :]) / d[None, :]) ** 2, axis=1))
    best = int(np.argmin(misfit))
    if misfit[best] > cfg.max_shape_residual:
        raise DegenerateGeometryError(f'vertices do not fit the target shape (misfit '
                                      f'{misfit[best]:.3f} > {cfg.max_shape_residual})')
    # Assignments equivalent under the model's symmetry give the same scale: only a different
    # scale with a near-equal misfit is a real ambiguity.
    other = np.abs(s / s[best] - 1.0) > 0.05
    if np.any(other) and misfit[other].min() < cfg.ambiguity_ratio * max(misfit[best], 1e-4):
        rival = s[other][np.argmin(misfit[other])]
        raise DegenerateGeometryError(f'{n} vertices fit the target at two scales '
                                      f'({s[best]:.4g} and {rival:.4g})')
    return perms[best], float(misfit[best])


def object_lengths(points: FloatArray, model_m: FloatArray,
                   cfg: ScaleConfig) -> tuple[FloatArray, FloatArray]:
    """(measured, true_m) lengths of every vertex pair of one object (see ``assign_to_model``)."""
    ids, _ = assign_to_model(points, model_m, cfg)
    pi, pj = _pair_index(len(points))
    measured = np.linalg.norm(points[pi] - points[pj], axis=1)
    true_m = np.linalg.norm(model_m[ids[pi]] - model_m[ids[pj]], axis=1)
    return measured, true_m


def regression_scale(measured: FloatArray, true_m: FloatArray) -> tuple[float, float]:
    """
    The paper's eq. 9-10: slope and intercept of ``true = S.F. * measured + B``.

    :raises DegenerateGeometryError: when the true lengths barely differ (e.g. only cube
        edges), since the slope is then set by noise alone.
    """
    x, y = np.asarray(measured, float), np.asarray(true_m, float)
    n = len(x)
    if n < 2 or np.ptp(y) < 1e-3 * np.mean(y):
        raise DegenerateGeometryError('eq. 9 needs lengths of different sizes (diagonals)')
    sf = (n * np.sum(x * y) - x.sum() * y.sum()) / (n * np.sum(x * x) - x.sum() ** 2)
    return float(sf), float((y.sum() - sf * x.sum()) / n)


def zero_intercept_scale(measured: FloatArray, true_m: FloatArray) -> tuple[float, float]:
    """Least-squares ``true = factor * measured`` (a length of 0 is 0 m); (factor, sigma)."""
    x, y = np.asarray(measured, float), np.asarray(true_m, float)
    factor = float(x @ y / (x @ x))
    dof = max(1, len(x) - 1)
    sigma = float(np.sqrt(np.sum((y - factor * x) ** 2) / dof / (x @ x)))
    return factor, sigma


def usable(n_obs: npt.NDArray[np.int64], angles_deg: FloatArray,
           cfg: ScaleConfig) -> npt.NDArray[np.bool_]:
    return (np.asarray(n_obs) >= cfg.min_observations) & \
        (np.asarray(angles_deg) >= cfg.min_angle_deg)


def without_duplicates(points: FloatArray, angles_deg: FloatArray, share: float,
                       corners: int = 0, apart: float = 0.0) -> npt.NDArray[np.int64]:
    """
    Indices of the vertices to keep: of those closer together than ``share`` of the median
    distance between all of them, the one seen under the widest angle. Then, while more remain
    than the target's ``corners``, of the closest two, if closer than ``apart`` of that median,
    the one seen under the wider angle (``share`` 0: nothing merged).

    A corner first reconstructed from afar (the live 60 s bag: 12-16 m, narrow angles) can lie a
    tenth of an edge from its second landmark, seen near, past ``share``; but a target cannot
    have more corners than its model, and a point nearer one corner than half the model's
    smallest corner distance is nearer it than any other.
    """
    if len(points) < 2 or share <= 0.0:
        return np.arange(len(points))
    dist = np.linalg.norm(points[:, None] - points[None, :], axis=2)
    median = float(np.median(dist[np.triu_indices(len(points), 1)]))
    angles = np.asarray(angles_deg)
    kept: list[int] = []
    for i in np.argsort(-angles, kind='stable'):
        if all(dist[i, j] >= share * median for j in kept):
            kept.append(int(i))
    while len(kept) > corners > 0:
        sub = dist[np.ix_(kept, kept)] + np.diag(np.full(len(kept), np.inf))
        a, b = np.unravel_index(int(np.argmin(sub)), sub.shape)
        if sub[a, b] >= apart * median:
            break
        kept.remove(kept[a] if angles[kept[a]] < angles[kept[b]] else kept[b])
    return np.sort(np.array(kept, np.int64))


def corner_gap(obj: 'ObjectVertices') -> float:
    """Half the smallest corner distance of ``obj``'s models, as a share of their median."""
    shares = []
    for size in (obj.size_m, *obj.alternatives):
        model = model_vertices_m(obj.kind, size)
        i, j = _pair_index(len(model))
        d = np.linalg.norm(model[i] - model[j], axis=1)
        shares.append(0.5 * float(d.min() / np.median(d)))
    return min(shares)


def drop_outlier_vertex(points: FloatArray, model_m: FloatArray,
                        cfg: ScaleConfig) -> tuple[npt.NDArray[np.int64], str | None]:
    """
    Leave out the one vertex that spoils the fit to the model, if one clearly does.

    :returns: indices of the vertices kept, and what was left out (None: nothing).
    """
    everything = np.arange(len(points))
    try:
        measured, true_m = object_lengths(points, model_m, cfg)
        ratio = true_m / measured
        med = np.median(ratio)
        mad = 1.4826 * np.median(np.abs(ratio - med)) + 1e-12
        if not np.any(np.abs(ratio - med) > cfg.outlier_sigma * mad):
            return everything, None
    except DegenerateGeometryError:
        if len(points) <= cfg.min_vertices:
            raise
    if len(points) <= cfg.min_vertices:
        return everything, None
    misfits = []
    for k in range(len(points)):
        try:
            misfits.append(assign_to_model(np.delete(points, k, axis=0), model_m, cfg)[1])
        except DegenerateGeometryError:
            misfits.append(np.inf)
    worst = int(np.argmin(misfits))
    if not np.isfinite(misfits[worst]):
        raise DegenerateGeometryError('no vertex subset fits the target shape')
    return np.delete(everything, worst), f'vertex {worst} left out (misfit ' \
        f'{misfits[worst]:.4f} without it)'


@dataclass(frozen=True, eq=False)
class ObjectVertices:
    """
    The reconstructed vertices of one calibration object.

    :param kind: 'sheet' or 'cube'.
    :param size_m: sheet (width, height) or cube (edge,), m.
    :param points: (N, 3) vertices, SfM units (any labelling; matched by shape).
    :param n_obs: (N,) keyframes that observed each vertex.
    :param angles_deg: (N,) widest triangulation angle of each vertex, degrees.
    :param object_id: the object's id, for messages.
    :param alternatives: other sizes the object may have (e.g. A4 when ``size_m`` is letter);
        the one the vertices fit is used, and a tie refuses the object.
    """

    kind: str
    size_m: tuple[float, ...]
    points: FloatArray
    n_obs: npt.NDArray[np.int64]
    angles_deg: FloatArray
    object_id: int = 0
    alternatives: tuple[tuple[float, ...], ...] = ()


def which_model(points: FloatArray, obj: ObjectVertices, cfg: ScaleConfig) -> FloatArray:
    """
    The model of ``obj`` (or of one of its ``alternatives``) that the vertices fit.

    :raises DegenerateGeometryError: when none fits, or two fit nearly equally well.
    """
    sizes = [obj.size_m, *obj.alternatives]
    if len(sizes) == 1:
        return model_vertices_m(obj.kind, obj.size_m)
    misfits = []
    for size in sizes:
        try:
            _, misfit = assign_to_model(points, model_vertices_m(obj.kind, size), cfg)
        except DegenerateGeometryError:
            misfit = np.inf
        misfits.append(misfit)
    order = np.argsort(misfits)
    best, second = misfits[order[0]], misfits[order[1]]
    if not np.isfinite(best):
        raise DegenerateGeometryError(f'vertices fit none of the sizes {sizes}')
    if second < cfg.ambiguity_ratio * max(best, 1e-4):
        raise DegenerateGeometryError(f'vertices fit both {sizes[order[0]]} and '
                                      f'{sizes[order[1]]} m: set the size in the config')
    return model_vertices_m(obj.kind, sizes[order[0]])


def estimate(objects: list[ObjectVertices], cfg: ScaleConfig,
             keyframes: int | None = None) -> ScaleEstimate:
    """
    Pool every usable object into one metric scale with its uncertainty.

    :param keyframes: keyframes in the reconstruction the vertices belong to (None: unknown,
        not checked).

    :raises NotObservableError: when no object passes the gate, or the factor is too
        uncertain; the message says why.
    """
    if keyframes is not None and keyframes < cfg.min_keyframes:
        raise NotObservableError(f'the reconstruction holds {keyframes} keyframes < '
                                 f'{cfg.min_keyframes}')
    measured, true_m, rejected = [], [], []
    for obj in objects:
        keep = usable(obj.n_obs, obj.angles_deg, cfg)
        pts = np.asarray(obj.points, float)[keep]
        single = without_duplicates(pts, np.asarray(obj.angles_deg)[keep], cfg.duplicate_share,
                                    len(model_vertices_m(obj.kind, obj.size_m)),
                                    corner_gap(obj))
        if len(single) < len(pts):
            rejected.append(f'object {obj.object_id}: {len(pts) - len(single)} vertices '
                            'reconstructed twice, merged')
            pts = pts[single]
        if len(pts) < cfg.min_vertices:
            rejected.append(f'object {obj.object_id}: {len(pts)} well-observed vertices < '
                            f'{cfg.min_vertices}')
            continue
        try:
            model = which_model(pts, obj, cfg)
            kept, dropped = drop_outlier_vertex(pts, model, cfg)
            pts = pts[kept]
            m, t = object_lengths(pts, model, cfg)
        except DegenerateGeometryError as err:
            rejected.append(f'object {obj.object_id}: {err}')
            continue
        if dropped:
            rejected.append(f'object {obj.object_id}: {dropped}')
        measured.append(m)
        true_m.append(t)
    if not measured:
        raise NotObservableError('; '.join(rejected) or 'no calibration object reconstructed')
    x, y = np.concatenate(measured), np.concatenate(true_m)
    factor, sigma = zero_intercept_scale(x, y)
    # Pairs share vertices, so they are not independent: count the vertices, not the pairs.
    n_vertices = sum(int(round((1 + np.sqrt(1 + 8 * len(m))) / 2)) for m in measured)
    sigma *= np.sqrt(len(x) / max(1, n_vertices - 1))
    # scipy.special, not scipy.stats: the same quantiles without stats' ~0.9 s import in the
    # middle of a run; imported here, not with the module, as the run's start (its processes
    # all importing at once) waited for its ~0.5 s.
    from scipy import special
    t_crit = float(special.stdtrit(max(1, n_vertices - 1), 0.5 + cfg.confidence / 2))
    # The drift term is a model, not a sample: it widens sigma but takes no t-correction.
    local = sigma
    sigma = float(np.hypot(local, cfg.drift_sigma_rel * factor))
    half = float(np.hypot(t_crit * local, special.ndtri(0.5 + cfg.confidence / 2)
                          * cfg.drift_sigma_rel * factor))
    if sigma / factor > cfg.max_relative_sigma:
        raise NotObservableError(f'scale too uncertain: sigma {100 * sigma / factor:.2f}% > '
                                 f'{100 * cfg.max_relative_sigma:.2f}% of the factor')
    return ScaleEstimate(factor, sigma, (factor - half, factor + half),
                         x, y, factor * x - y, len(measured), rejected)


SLOW_STEP_SHARE = 0.3  # steps shorter than this share of the path's median are not judged


def check_path(centres: FloatArray, stamps_ns: npt.NDArray[np.int64], cfg: ScaleConfig) -> None:
    """
    Refuse a keyframe path with an implausible jump (see ``ScaleConfig.max_path_jump``).

    :param centres: (N, 3) keyframe camera centres, SfM units, in stamp order.
    :param stamps_ns: (N,) their stamps.
    :raises NotObservableError: naming the keyframe where the path jumps.
    """
    if cfg.max_path_jump <= 0.0 or len(centres) < 3:
        return
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    # Two short steps (a camera nearly still or turning on the spot) are mostly pose noise, and
    # noise alone reverses their velocity; an aliased link is a long step (a texture period).
    floor = SLOW_STEP_SHARE * float(np.median(steps))
    for k in range(len(centres) - 2):
        why = aliasing.velocity_reason(centres[k:k + 3], stamps_ns[k:k + 3], cfg.max_path_jump,
                                       cfg.path_jump_s, floor)
        if why is not None:
            raise NotObservableError(f'the keyframe path jumps at keyframe {k + 2}{why}: the map '
                                     f'is bent there, no single factor scales it')


def group_objects(points: FloatArray, object_ids: npt.NDArray[np.int64],
                  target_types: npt.NDArray[np.int64], n_obs: npt.NDArray[np.int64],
                  angles_deg: FloatArray, sheet_m: tuple[float, float],
                  cube_edge_m: float,
                  sheet_alternatives: tuple[tuple[float, float], ...] = ()
                  ) -> list[ObjectVertices]:
    """
    Split labelled target landmarks into one ``ObjectVertices`` per object.

    :param target_types: (N,) 0 sheet, 1 cube (``targets.TARGET_TYPE_CODES``).
    :param sheet_alternatives: other sheet sizes to try (see ``ObjectVertices``).
    """
    objects = []
    for oid in np.unique(object_ids):
        sel = object_ids == oid
        kinds = np.unique(target_types[sel])
        if len(kinds) != 1 or int(kinds[0]) not in (0, 1):
            continue  # mixed or unknown kinds under one id: not a target we can measure
        sheet = kinds[0] == 0
        kind, size = ('sheet', tuple(sheet_m)) if sheet else ('cube', (cube_edge_m,))
        objects.append(ObjectVertices(kind, size, points[sel], n_obs[sel], angles_deg[sel],
                                      int(oid), sheet_alternatives if sheet else ()))
    return objects


def apply_to_positions(poses: FloatArray, factor: float) -> FloatArray:
    """(N, 7) poses ``x y z qx qy qz qw`` with positions scaled to metres."""
    scaled = np.array(poses, dtype=np.float64, copy=True)
    scaled[:, :3] *= factor
    return scaled
