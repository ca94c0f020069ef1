"""CameraInfo <-> CameraModel (conversions), on rclpy and rosbags messages."""
from absscale_ros import conversions
from absscale_ros.core import errors
from absscale_ros.core.types import CameraModel
from conversions_helpers import READERS
import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo

K = np.array([[612.5, 0.0, 319.25], [0.0, 610.0, 241.5], [0.0, 0.0, 1.0]])
DISTORTIONS = {
    'plumb_bob': [-0.28, 0.07, 1e-3, -2e-4, 0.01],
    'rational_polynomial': [0.1, -0.2, 1e-3, 2e-3, 0.05, 0.2, -0.1, 0.03],
    'equidistant': [0.01, -0.02, 0.003, -0.0004],
}


def info(**fields: object) -> CameraInfo:
    msg = conversions.camera_model_to_info_msg(CameraModel(640, 480, K))
    for name, value in fields.items():
        setattr(msg, name, value)
    return msg


def project(model: CameraModel, point_cam_m: np.ndarray) -> np.ndarray:
    """Pinhole projection of a point in the camera frame to pixels."""
    uvw = model.K @ point_cam_m
    return uvw[:2] / uvw[2]


@pytest.mark.parametrize('reader', READERS)
@pytest.mark.parametrize('model_name', DISTORTIONS)
def test_each_distortion_model_round_trips(model_name: str, reader: str) -> None:
    model = CameraModel(640, 480, K, np.array(DISTORTIONS[model_name]), model_name)
    msg = conversions.camera_model_to_info_msg(model, stamp_ns=77, frame_id='camera_optical')
    assert msg.distortion_model == model_name
    np.testing.assert_array_equal(np.reshape(msg.r, (3, 3)), np.eye(3))
    np.testing.assert_array_equal(np.reshape(msg.p, (3, 4)), np.hstack([K, np.zeros((3, 1))]))
    back = conversions.camera_info_to_model(READERS[reader](msg))
    assert (back.width, back.height, back.distortion_model) == (640, 480, model_name)
    np.testing.assert_array_equal(back.K, K)
    np.testing.assert_array_equal(back.dist, DISTORTIONS[model_name])
    assert msg.header.frame_id == 'camera_optical'
    assert conversions.stamp_to_ns(msg.header.stamp) == 77


@pytest.mark.parametrize('reader', READERS)
def test_model_without_distortion_goes_out_as_zero_plumb_bob(reader: str) -> None:
    msg = conversions.camera_model_to_info_msg(CameraModel(640, 480, K))
    assert msg.distortion_model == 'plumb_bob'
    assert list(msg.d) == [0.0] * 5
    back = conversions.camera_info_to_model(READERS[reader](msg))
    assert not back.has_distortion
    np.testing.assert_array_equal(back.K, K)


@pytest.mark.parametrize('reader', READERS)
def test_empty_d_or_empty_model_means_no_distortion(reader: str) -> None:
    for fields in ({'d': []}, {'distortion_model': '', 'd': []},
                   {'distortion_model': '', 'd': [0.0] * 5},
                   {'distortion_model': 'none', 'd': [0.0] * 5}):
        model = conversions.camera_info_to_model(READERS[reader](info(**fields)))
        assert model.distortion_model == 'none', fields
        assert model.dist.size == 0


def test_plumb_bob_with_four_coefficients_gets_a_zero_k3() -> None:
    model = conversions.camera_info_to_model(info(d=[0.1, 0.2, 0.003, 0.004]))
    np.testing.assert_array_equal(model.dist, [0.1, 0.2, 0.003, 0.004, 0.0])


@pytest.mark.parametrize('reader', READERS)
def test_binning_and_roi_give_the_published_image_size_and_k(reader: str) -> None:
    msg = info(binning_x=2, binning_y=2)
    msg.roi.x_offset, msg.roi.y_offset, msg.roi.width, msg.roi.height = 40, 20, 400, 300
    model = conversions.camera_info_to_model(READERS[reader](msg))
    assert (model.width, model.height) == (200, 150)
    np.testing.assert_allclose(model.K, [[K[0, 0] / 2, 0, (K[0, 2] - 40) / 2],
                                         [0, K[1, 1] / 2, (K[1, 2] - 20) / 2], [0, 0, 1]])


@pytest.mark.parametrize('width,height', [(320, 240), (1280, 960), (100, 50)])
def test_resized_model_round_trip_scales_projections_with_the_image(width: int,
                                                                    height: int) -> None:
    model = CameraModel(640, 480, K, np.array(DISTORTIONS['plumb_bob']), 'plumb_bob')
    resized = model.resized(width, height)
    back = conversions.camera_info_to_model(conversions.camera_model_to_info_msg(resized))
    assert (back.width, back.height) == (width, height)
    sx, sy = width / 640, height / 480
    for point_cam_m in ([0.0, 0.0, 2.0], [0.3, -0.2, 1.5], [-1.0, 0.7, 4.0]):
        u, v = project(model, np.array(point_cam_m))
        # Same ray, pixel centres at integer coordinates: u' + 0.5 = (u + 0.5) * sx.
        np.testing.assert_allclose(project(back, np.array(point_cam_m)),
                                   [(u + 0.5) * sx - 0.5, (v + 0.5) * sy - 0.5], atol=1e-9)
    np.testing.assert_array_equal(back.dist, model.dist)


@pytest.mark.parametrize('reader', READERS)
@pytest.mark.parametrize('fields,match', [
    ({'width': 0}, r'size is 0x480'),
    ({'height': 0}, r'size is 640x0'),
    ({'k': np.zeros(9)}, 'not calibrated'),
    ({'k': np.array([np.nan, 0, 320, 0, 500, 240, 0, 0, 1.0])}, 'NaN or inf'),
    ({'d': [0.1, np.inf, 0, 0, 0]}, 'NaN or inf'),
    ({'k': np.array([-500.0, 0, 320, 0, 500, 240, 0, 0, 1])}, r'fx=-500\.0'),
    ({'distortion_model': 'plumb_bob', 'd': [0.1, 0.2, 0.0]}, 'needs 5 D coefficients, got 3'),
    ({'distortion_model': 'equidistant', 'd': [0.1] * 5}, 'needs 4 D coefficients, got 5'),
    ({'distortion_model': 'fancy_lens', 'd': [0.1]}, "'fancy_lens'"),
    ({'distortion_model': '', 'd': [0.1, 0, 0, 0, 0]}, 'no distortion_model'),
    ({'binning_x': 1000}, 'invalid camera'),
])
def test_malformed_camera_info_is_rejected(fields: dict, match: str, reader: str) -> None:
    with pytest.raises(errors.MessageError, match=match):
        conversions.camera_info_to_model(READERS[reader](info(**fields)))
