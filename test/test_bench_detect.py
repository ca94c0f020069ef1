"""``absscale bench detect`` on a tiny bag of rendered cube frames with a gt.json beside it."""
import json
from pathlib import Path
import sys

import numpy as np
from rclpy.serialization import serialize_message

from absscale_ros import bagio, conversions
from absscale_ros.core import targets
from absscale_ros.tools import bench_detect

sys.path.insert(0, str(Path(__file__).parent / 'core'))
import synth_targets as st  # noqa: E402


def _write(path: Path) -> None:
    rng = np.random.default_rng(3)
    model = targets.CubeModel()
    face_ids = {}
    gt_faces = []
    for axis, colour in enumerate(targets.CUBE_COLOURS):
        for side in (0, 1):
            face_ids[(axis, side)] = len(gt_faces)
            gt_faces.append({'id': len(gt_faces), 'vertex_ids': [], 'colour': colour})
    frames = []
    with bagio.BagWriter(path) as writer:
        for k, (yaw, dist) in enumerate([(35, 5.0), (50, 4.0), (20, 4.5), (None, None)]):
            if yaw is None:
                img = st._finish(st._background(rng), rng)
                tf = []
            else:
                R, t = st.cube_pose(yaw, 25, dist)
                img, faces, v_px = st.render_cube(rng, R, t)
                fs = []
                for colour, poly, order in faces:
                    axis = targets.CUBE_COLOURS.index(colour)
                    fid = face_ids[(axis, (order[0] >> axis) & 1)]
                    fs.append({'id': fid, 'area_px': 0, 'holes_px': [],
                               'polygons_px': [np.round(poly).astype(int).tolist()]})
                vis = [any(i in f[2] for f in faces) for i in range(8)]
                tf = [{'id': 0, 'vertices_px': v_px.tolist(), 'vertex_visible': vis,
                       'area_fraction': 0.05, 'covers_min_area': True, 'faces': fs}]
            stamp = 1_000_000_000 + k * 33_333_333
            msg = conversions.bgr_to_compressed_msg(img, 'jpeg', 95, stamp, 'camera')
            writer.write('/camera/image_raw/compressed', 'sensor_msgs/msg/CompressedImage',
                         stamp, serialize_message(msg))
            frames.append({'index': k, 'stamp_ns': stamp, 'targets': tf})
    gt = {'scene': {'name': 'outdoor_cube', 'seed': 0, 'variant': {'target': 'cube'}},
          'bag': {'image_topic': '/camera/image_raw/compressed'},
          'camera': {'width': st.W, 'height': st.H, 'K': st.K.tolist()},
          'targets': [{'id': 0, 'kind': 'cube', 'name': 'cube_0.8',
                       'edges': model.edges().tolist(), 'faces': gt_faces}],
          'frames': frames}
    Path(str(path) + '.gt.json').write_text(json.dumps(gt))


def test_bench_detect_figures(tmp_path, capsys):
    bag = tmp_path / 'cube.mcap'
    _write(bag)
    tally = bench_detect.Tally()
    bench_detect.bench_bag(str(bag), 'from-gt', 0, tally)
    fig = bench_detect.figures(tally)
    for colour in ('red', 'yellow', 'purple'):
        assert fig[colour]['precision_pct'] > 97.0 and fig[colour]['recall_pct'] > 95.0
    assert fig['sheet']['precision_pct'] is None
    assert fig['cube_corner']['median_rel'] < 0.005
    assert fig['detection_rate_pct'] == 100.0 and fig['eligible_frames'] == 3
    assert fig['frames_without_target'] == 1 and fig['false_vertex_frames_pct'] == 0.0
    assert fig['time_ms']['frames'] == 4
    args = type('A', (), {'bags': [str(bag)], 'target': 'from-gt', 'max_frames': 0,
                          'json': False, 'threads': 1})
    assert bench_detect.run(args) == 0
    assert 'Table 2' in capsys.readouterr().out


def test_poly_mask_counts_pixel_centres_inside_only():
    # cv2.fillPoly also fills the pixels the outline touches: ~0.5 px all round
    rng = np.random.default_rng(5)
    for _ in range(5):
        quad = np.array([[40.0, 30.0], [160.0, 45.0], [150.0, 120.0], [35.0, 100.0]])
        quad += rng.uniform(-0.5, 0.5, quad.shape)
        m = bench_detect._poly_mask((160, 200), quad)
        vs, us = np.mgrid[0:160, 0:200]
        pts = np.stack([us.ravel(), vs.ravel()], axis=1).astype(float)
        inside = bench_detect._inside(pts, quad).reshape(160, 200)
        assert np.array_equal(m, inside)
        d1, d2 = quad[2] - quad[0], quad[3] - quad[1]
        area = 0.5 * abs(d1[0] * d2[1] - d1[1] * d2[0])  # np.cross of 2-vectors is deprecated
        assert abs(int(m.sum()) - area) < 0.01 * area
