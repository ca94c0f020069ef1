"""Config files read as ROS reads them; the run picture draws real data."""
from pathlib import Path

from absscale_ros import params, run_figure
from absscale_ros.core.errors import AbsScaleError
import cv2
import numpy as np
import pytest


def test_every_shipped_config_loads_with_nested_names() -> None:
    for name in params.CONFIG_NAMES:
        sections = params.load_yaml(params.find_config(name))
        assert 'bag_replay' in sections and 'scale' in sections
        assert all('.' in k or not isinstance(v, dict)
                   for section in sections.values() for k, v in section.items())


def test_nested_yaml_flattens_and_wildcard_merges(tmp_path: Path) -> None:
    f = tmp_path / 'c.yaml'
    f.write_text('/**:\n  ros__parameters:\n    qos: sensor_data\n'
                 'det:\n  ros__parameters:\n    sheet:\n      aspect_tol: 0.1\n')
    merged = params.node_params(params.load_yaml(f), 'det')
    assert merged == {'qos': 'sensor_data', 'sheet.aspect_tol': 0.1}
    with pytest.raises(AbsScaleError, match='unknown config'):
        params.find_config('no_such_config')
    f.write_text('det: [1, 2]\n')
    with pytest.raises(AbsScaleError, match='ros__parameters'):
        params.load_yaml(f)


def test_dds_profile_holds_a_whole_frame_unless_the_user_chose_one(monkeypatch) -> None:
    import xml.etree.ElementTree as ET
    monkeypatch.delenv(params.DDS_PROFILE_VARIABLE, raising=False)
    path = Path(params.dds_environment()[params.DDS_PROFILE_VARIABLE])
    ns = {'f': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}
    shm, = [d for d in ET.parse(path).getroot().iterfind('.//f:transport_descriptor', ns)
            if d.findtext('f:type', namespaces=ns) == 'SHM']
    frame_bytes = 1280 * 720 * 3
    assert int(shm.findtext('f:maxMessageSize', namespaces=ns)) > frame_bytes
    assert int(shm.findtext('f:segment_size', namespaces=ns)) >= 8 * frame_bytes
    monkeypatch.setenv(params.DDS_PROFILE_VARIABLE, '/somewhere/mine.xml')
    assert params.dds_environment() == {}


def test_run_picture_has_three_panels_of_data(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    cloud = rng.uniform(-3, 3, size=(500, 3))
    history = [{'stamp_ns': i * 10**8, 'factor': 0.5 + 0.01 / (i + 1), 'sigma': 0.001}
               for i in range(10)]
    detections = [(i * 33_333_333, 4 if 10 < i < 50 else 0) for i in range(60)]
    quats = np.tile([-0.7071, 0.0, 0.0, 0.7071], (5, 1))  # optical y axis along world -z
    up = run_figure.up_from_cameras(quats)
    assert np.allclose(up, [0, 0, 1], atol=1e-3)
    run_figure.draw_run(tmp_path / 'run.png', detections, history, cloud,
                        rng.integers(0, 255, (500, 3)).astype(np.uint8), cloud[:5], up, 't')
    img = cv2.imread(str(tmp_path / 'run.png'))
    assert img is not None and img.shape[1] > 1000 and img.std() > 10
