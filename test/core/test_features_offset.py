"""SIFT keypoint positions against the image's mirror (``FeatureConfig.sift_offset_px``)."""
from dataclasses import replace
from pathlib import Path
import sys

import numpy as np
import pytest
from scipy.spatial import cKDTree

from absscale_ros.core import features as feat

sys.path.insert(0, str(Path(__file__).parent))
import sfm_scenes  # noqa: E402


@pytest.fixture(scope='module')
def frame():
    """One rendered 1280 px outdoor keyframe (detection on its 640 px copy)."""
    seq = sfm_scenes.make_sequence('outdoor_cube', 3, count=1, width=1280)
    return seq.images_bgr[0], seq.camera


def _mirror_shift_px(image, camera, cfg, axis: int) -> float:
    """
    Median of x - x' over keypoints found in ``image`` and in its mirror about ``axis`` (x' the
    mirrored keypoint mapped back): twice the detector's bias along that axis, full-size px.
    """
    a = feat.detect(image, camera, cfg).keypoints_px
    b = feat.detect(np.ascontiguousarray(np.flip(image, 1 - axis)), camera, cfg).keypoints_px
    b[:, axis] = image.shape[1 - axis] - 1 - b[:, axis]
    d, j = cKDTree(b).query(a, distance_upper_bound=1.5)
    ok = np.isfinite(d)
    assert ok.sum() > 300
    return float(np.median(a[ok, axis] - b[j[ok], axis]))


@pytest.mark.parametrize('axis', [0, 1])
def test_sift_keypoints_agree_with_the_mirror_image(frame, axis):
    image, camera = frame
    cfg = feat.FeatureConfig()
    # Uncorrected (the default), the upsampling puts each keypoint 0.25 px of the 640 px copy
    # (0.5 full-size px) right of / below the feature: 1 px between an image and its mirror.
    assert cfg.sift_offset_px == 0.0
    assert _mirror_shift_px(image, camera, cfg, axis) == pytest.approx(1.0, abs=0.05)
    fixed = replace(cfg, sift_offset_px=0.25)
    assert abs(_mirror_shift_px(image, camera, fixed, axis)) < 0.05


def test_offset_leaves_orb_alone(frame):
    image, camera = frame
    cfg = feat.FeatureConfig(detector='orb')
    a = feat.detect(image, camera, cfg)
    b = feat.detect(image, camera, replace(cfg, sift_offset_px=0.25))
    assert len(a.keypoints_px) > 100 and np.array_equal(a.keypoints_px, b.keypoints_px)


@pytest.mark.parametrize('name', feat.DETECTORS)
def test_every_offered_detector_exists(frame, name):
    """Each detector the config accepts must exist in the installed OpenCV (5.0 dropped
    AKAZE from its main modules, which only failed once a map was built)."""
    image, camera = frame
    assert len(feat.detect(image, camera, feat.FeatureConfig(detector=name)).keypoints_px) > 100


def test_an_unknown_detector_is_refused_at_configuration():
    with pytest.raises(ValueError, match='akaze'):
        feat.FeatureConfig(detector='akaze')
