"""
The bench's reference: the same keyframe images through pycolmap's incremental mapping.

The camera is fixed to the CameraInfo model (OPENCV: fx fy cx cy k1 k2 p1 p2, one shared
camera), features are COLMAP's SIFT, matching is exhaustive. Timing covers extraction, matching
and mapping, not writing the images.
"""
from pathlib import Path
import tempfile
import time
from typing import Any

import cv2
import numpy as np

from absscale_ros.core import align
from absscale_ros.core.types import CameraModel


def run(camera: CameraModel, images_bgr: list[np.ndarray],
        T_world_cams_gt: dict[int, np.ndarray]) -> dict[str, Any]:
    """Map ``images_bgr`` (keyframe id = index) and score camera centres like ours."""
    try:
        import pycolmap
    except ImportError:
        return {'error': 'pycolmap not installed (pip install -r requirements-dev.txt)'}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        (root / 'images').mkdir()
        for k, img in enumerate(images_bgr):
            cv2.imwrite(str(root / 'images' / f'{k:05d}.png'), img)
        K, d = camera.K, np.zeros(4)
        d[:min(4, camera.dist.size)] = camera.dist[:4]
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = 'OPENCV'
        reader.camera_params = ','.join(str(float(x)) for x in
                                        (K[0, 0], K[1, 1], K[0, 2], K[1, 2], *d))
        opts = pycolmap.IncrementalPipelineOptions()
        opts.ba_refine_focal_length = False
        opts.ba_refine_principal_point = False
        opts.ba_refine_extra_params = False
        t0 = time.perf_counter()
        db = root / 'db.db'
        pycolmap.extract_features(db, root / 'images', camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=reader)
        pycolmap.match_exhaustive(db)
        maps = pycolmap.incremental_mapping(db, root / 'images', root / 'out', options=opts)
        elapsed = time.perf_counter() - t0
    if not maps:
        return {'error': 'no reconstruction', 'time_s': elapsed, 'registered': 0}
    rec = max(maps.values(), key=lambda r: r.num_reg_images())
    est, gt = [], []
    for image in rec.images.values():
        if not image.has_pose:
            continue
        # pycolmap 4 returns the centre as a (3, 1) column: flatten, or the alignment is nonsense.
        est.append(np.asarray(image.projection_center(), np.float64).reshape(3))
        gt.append(T_world_cams_gt[int(Path(image.name).stem)][:3, 3])
    out = {'time_s': elapsed, 'registered': len(est), 'models': len(maps)}
    if len(est) >= 3:
        s, R, t = align.umeyama(np.array(est), np.array(gt))
        out['centre_rmse_m'] = align.rmse(align.apply(s, R, t, np.array(est)), np.array(gt))
        length = float(np.sum(np.linalg.norm(np.diff(np.array(
            [T_world_cams_gt[k][:3, 3] for k in sorted(T_world_cams_gt)]), axis=0), axis=1)))
        out['centre_rmse_pct'] = 100.0 * out['centre_rmse_m'] / length
    return out
