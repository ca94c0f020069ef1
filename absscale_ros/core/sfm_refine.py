"""
Which observations ``IncrementalSfm`` refines at full resolution (``landmark_refine``), and the
images and tiles that takes: the undistorted grey images of the newest keyframes, the
(landmark, keyframe) observations already aligned, and each landmark's reference tile, which
it is aligned from into every new keyframe while its reference image is kept.
"""
import numpy as np
import numpy.typing as npt

from absscale_ros.core import landmark_refine, sfm_map
from absscale_ros.core.types import CameraModel

FloatArray = npt.NDArray[np.float64]
Grey = npt.NDArray[np.uint8]


class ObservationRefiner:
    """Refinement state of one ``IncrementalSfm`` (``cfg.max_observations`` 0: does nothing)."""

    def __init__(self, camera: CameraModel, cfg: landmark_refine.RefineConfig) -> None:
        self.cfg, self.K = cfg, camera.K
        self._undistort = landmark_refine.undistort_maps(camera) \
            if cfg.max_observations > 0 and camera.has_distortion else None
        self.grey: dict[int, Grey] = {}  # by keyframe id
        # By keyframe (dropped with its image): the landmarks aligned into it, and the
        # reference tiles cut from it (landmark -> the observation it is centred on, the tile).
        self._refined: dict[int, set[int]] = {}
        self._tiles: dict[int, dict[int, tuple[FloatArray, Grey]]] = {}

    @property
    def enabled(self) -> bool:
        return self.cfg.max_observations > 0

    def add_image(self, kf_id: int, image_bgr: npt.NDArray[np.uint8]) -> None:
        """Keep keyframe ``kf_id``'s image, (H, W, 3) uint8 BGR, as undistorted grey."""
        if self.enabled:
            self.grey[kf_id] = landmark_refine.undistorted_grey(image_bgr, self._undistort)

    def keep(self, kf_ids: set[int]) -> None:
        """Keep the images (and what was aligned into them) of the newest ``keep_images`` of
        the keyframes ``kf_ids`` (those of the current map and its pending ones)."""
        if not self.grey:
            return
        kept = set([k for k in sorted(self.grey) if k in kf_ids][-self.cfg.keep_images:])
        self.grey = {k: v for k, v in self.grey.items() if k in kept}
        self._refined = {k: v for k, v in self._refined.items() if k in kept}
        self._tiles = {k: v for k, v in self._tiles.items() if k in kept}

    def refine(self, m: sfm_map.SfmMap, kf: sfm_map.MapKeyframe) -> int:
        """
        Align the observations of the landmarks ``kf`` sees, up to ``max_observations`` (those
        of the landmarks with the most views first), each to the landmark's oldest observation
        with an image kept; returns how many moved (a failed alignment keeps the detected
        position).
        """
        cfg, grey, lms = self.cfg, self.grey, m.landmarks
        if cfg.max_observations <= 0:
            return 0
        seen = np.unique(kf.landmark_of[kf.landmark_of >= 0]).tolist()
        todo, done, none = [], self._refined, set()
        for lm_id in seen:
            lm = lms.get(lm_id)
            if lm is None or lm.label is not None or len(lm.obs_px) < cfg.min_views:
                continue
            kept = [k for k in lm.obs_px if k in grey]
            if len(kept) > 1:
                kept.sort()
                todo += [(-len(lm.obs_px), lm_id, kept[0], k) for k in kept[1:]
                         if lm_id not in done.get(k, none)]
        todo = sorted(todo)[:cfg.max_observations]
        if not todo:
            return 0
        cloud = np.array([lms[i].point_world for i in seen if i in lms])
        groups: dict[tuple[int, int], list[int]] = {}
        for _, lm_id, a, k in todo:
            groups.setdefault((a, k), []).append(lm_id)
        # One normal per landmark, though it is aligned into several keyframes (one KD-tree).
        ids = sorted({lm_id for _, lm_id, _, _ in todo})
        normal_of = dict(zip(ids, landmark_refine.plane_normals(
            np.array([lms[i].point_world for i in ids]), cloud, cfg.neighbours)))
        # Every (reference, keyframe) pair's patches in one alignment, pair after pair (a
        # landmark's reference observation is never one that is refined, so their order does
        # not matter).
        pairs, entries, uv_a, tiles = [], [], [], []
        for (a, k), group in sorted(groups.items()):
            uv = np.array([lms[i].obs_px[a] for i in group])
            pairs.append((grey[k], m.keyframes[a].T_world_cam, m.keyframes[k].T_world_cam,
                          len(group)))
            entries += [(i, k) for i in group]
            uv_a.append(uv)
            tiles.append(self._ref_tiles(a, group, uv))
        lm_ids = [i for i, _ in entries]
        uv, ok = landmark_refine.align_pairs(
            pairs, self.K, np.array([lms[i].point_world for i in lm_ids]),
            np.array([normal_of[i] for i in lm_ids]), np.concatenate(uv_a),
            np.concatenate(tiles), cfg)
        for lm_id, k in entries:
            self._refined.setdefault(k, set()).add(lm_id)
        moved = 0
        for (lm_id, k), uv_k, good in zip(entries, uv, ok.tolist()):
            if good:
                lms[lm_id].obs_px[k] = uv_k
                m.dirty.add(lm_id)
                moved += 1
        return moved

    def _ref_tiles(self, a: int, group: list[int], uv_a: FloatArray) -> Grey:
        """The reference tiles of landmarks ``group`` at ``uv_a`` (N, 2) in keyframe ``a``,
        each cut once (cutting them was a tenth of the alignment's CPU)."""
        tiles, nan = self._tiles.setdefault(a, {}), np.full(2, np.nan)  # nan: never equal
        have = np.array([tiles[i][0] if i in tiles else nan for i in group])
        new = np.flatnonzero(~np.all(have == uv_a, axis=1)).tolist()
        if new:
            cut = landmark_refine.ref_tiles(self.grey[a], uv_a[new], self.cfg)
            for j, tile in zip(new, cut):
                tiles[group[j]] = (uv_a[j], tile)
        return np.stack([tiles[i][1] for i in group])
