"""gt.json: schema, projection agreement, pixel colours at target corners, 3D truth."""
import colorsys
import copy

import cv2
import numpy as np
import pytest

from absscale_ros.sim import groundtruth, simulation
from absscale_ros.sim.scene import SKY


def test_schema_validates_and_rejects(outdoor_bag: tuple) -> None:
    _, gt = outdoor_bag
    groundtruth.validate(gt)
    assert gt['bag']['frame_count'] == len(gt['frames']) == 40
    for mutate in (lambda g: g.pop('camera'),
                   lambda g: g['frames'][3].update(index=7),
                   lambda g: g['frames'][0]['targets'][0]['vertex_visible'].pop(),
                   lambda g: g['point_pairs'][0].update(distance_m=1.0),
                   lambda g: g['frames'][1]['T_world_cam'][0].__setitem__(0, 2.0),
                   lambda g: g.update(schema_version=99)):
        bad = copy.deepcopy(gt)
        mutate(bad)
        with pytest.raises(ValueError):
            groundtruth.validate(bad)


@pytest.mark.parametrize('bag', ['outdoor_bag', 'indoor_bag'])
def test_vertices_agree_with_projection_through_bag_intrinsics(bag: str,
                                                               request: pytest.FixtureRequest
                                                               ) -> None:
    _, gt = request.getfixturevalue(bag)
    cam = gt['camera']
    K, D = np.array(cam['K']), np.array(cam['D'])
    worst, checked = 0.0, 0
    for f in gt['frames']:
        T = np.array(f['T_world_cam'])
        for tgt, ft in zip(gt['targets'], f['targets']):
            pts_cam = (np.array(tgt['vertices_world_m']) - T[:3, 3]) @ T[:3, :3]
            uv, _ = cv2.projectPoints(pts_cam, np.zeros(3), np.zeros(3), K, D)
            for p, q, z in zip(ft['vertices_px'], uv.reshape(-1, 2), pts_cam[:, 2]):
                if z > 0 and p is not None:
                    worst = max(worst, float(np.abs(np.subtract(p, q)).max()))
                    checked += 1
    assert checked > 100
    assert worst < 0.01


def _visible_frame(gt: dict, min_area: float) -> int:
    best = max(gt['frames'], key=lambda f: f['targets'][0]['area_fraction'])
    assert best['targets'][0]['area_fraction'] > min_area
    return int(best['index'])


def _hsv(rgb: np.ndarray) -> tuple[float, float, float]:
    h, s, v = colorsys.rgb_to_hsv(*(np.clip(rgb, 0, 255) / 255.0))
    return h * 360.0, s, v


def test_sheet_corners_inside_bright_outside_darker(indoor_bag: tuple) -> None:
    """Rendered pixels 2 px inside each visible sheet corner are paper, 2 px outside are not."""
    _, gt = indoor_bag
    k = _visible_frame(gt, 0.002)
    r = groundtruth.renderer_for(gt)
    frame = r.render(np.array(gt['frames'][k]['T_world_cam']))
    ft = gt['frames'][k]['targets'][0]
    corners = np.array([p for p in ft['vertices_px']])
    centre = corners.mean(axis=0)
    for p, vis in zip(corners, ft['vertex_visible']):
        if not vis:
            continue
        inward = (centre - p) / np.linalg.norm(centre - p)
        inside = np.rint(p + 2.0 * inward).astype(int)
        outside = np.rint(p - 2.0 * inward).astype(int)
        sid_in = frame.surface[inside[1], inside[0]]
        assert r.scene.surface_target[sid_in] == 0
        assert r.scene.surface_target[frame.surface[outside[1], outside[0]]] != 0
        v_in = frame.colour[inside[1], inside[0]].mean()
        v_out = frame.colour[outside[1], outside[0]].mean()
        assert v_in > 150 and v_in > v_out + 40


def test_cube_faces_have_their_colours_and_edges_are_sharp(outdoor_bag: tuple) -> None:
    _, gt = outdoor_bag
    k = _visible_frame(gt, 0.004)
    r = groundtruth.renderer_for(gt)
    T = np.array(gt['frames'][k]['T_world_cam'])
    frame = r.render(T)
    ft = gt['frames'][k]['targets'][0]
    uv = np.array(ft['vertices_px'])
    target = gt['targets'][0]
    hues = {'red': 0.0, 'yellow': 55.0, 'purple': 290.0}
    seen = 0
    for face in ft['faces']:
        spec = target['faces'][face['id']]
        if face['area_px'] < 150:
            continue
        corners = uv[spec['vertex_ids']]
        centre = corners.mean(axis=0)
        for p in corners:  # just inside each corner, towards the face centre
            q = np.rint(p + 0.2 * (centre - p)).astype(int)
            if r.scene.surface_face[frame.surface[q[1], q[0]]] != face['id']:
                continue  # this corner is hidden behind another face
            h, s, _ = _hsv(frame.colour[q[1], q[0]])
            assert abs((h - hues[spec['colour']] + 180.0) % 360.0 - 180.0) < 12.0
            assert s > 0.6
            seen += 1
    assert seen >= 4
    # Just outside the silhouette: 3 px beyond each visible vertex, away from the cube.
    centre = uv.mean(axis=0)
    for p, vis in zip(uv, ft['vertex_visible']):
        q = np.rint(p + 3.0 * (p - centre) / np.linalg.norm(p - centre)).astype(int)
        if vis and 0 <= q[0] < gt['camera']['width'] and 0 <= q[1] < gt['camera']['height']:
            sid = frame.surface[q[1], q[0]]
            assert sid == SKY or r.scene.surface_target[sid] != 0


def test_face_outlines_match_the_render(outdoor_bag: tuple) -> None:
    _, gt = outdoor_bag
    k = _visible_frame(gt, 0.004)
    r = groundtruth.renderer_for(gt)
    frame = r.render(np.array(gt['frames'][k]['T_world_cam']))
    for face in gt['frames'][k]['targets'][0]['faces']:
        mask = np.zeros(frame.surface.shape, np.uint8)
        cv2.fillPoly(mask, [np.array(p, np.int32) for p in face['polygons_px']], 1)
        for hole in face['holes_px']:
            cv2.fillPoly(mask, [np.array(hole, np.int32)], 0)
        sid = np.flatnonzero((r.scene.surface_target == 0) & (r.scene.surface_face == face['id']))
        truth = frame.surface == sid[0]
        assert truth.sum() == face['area_px']
        assert np.logical_xor(mask > 0, truth).sum() <= 0.1 * face['area_px'] + 20


def test_points_behind_pixels_hit_the_target(outdoor_bag: tuple) -> None:
    _, gt = outdoor_bag
    k = _visible_frame(gt, 0.004)
    ft = gt['frames'][k]['targets'][0]
    verts = np.array(gt['targets'][0]['vertices_world_m'])
    uv = np.array(ft['vertices_px'])
    centre_px = uv[ft['vertex_visible']].mean(axis=0)
    pts = groundtruth.points_behind_pixels(gt, k, np.vstack([centre_px, [320.0, 2.0]]))
    c = verts.mean(axis=0)
    axes = np.stack([verts[1] - verts[0], verts[2] - verts[0], verts[4] - verts[0]]) / 0.8
    local = axes @ (pts[0] - c)  # in the cube's own frame: on its surface
    assert np.all(np.abs(local) <= 0.4 + 1e-4) and np.isclose(np.abs(local).max(), 0.4, atol=1e-4)
    depth = groundtruth.depth_map(gt, k)
    T = np.array(gt['frames'][k]['T_world_cam'])
    q = np.rint(centre_px).astype(int)
    p = groundtruth.points_behind_pixels(gt, k, q[None].astype(float))[0]
    assert ((p - T[:3, 3]) @ T[:3, :3])[2] == pytest.approx(depth[q[1], q[0]], abs=1e-3)


def test_pure_rotation_segments_keep_the_centre(outdoor_bag: tuple, indoor_bag: tuple) -> None:
    for _, gt in (outdoor_bag, indoor_bag):
        segs = gt['pure_rotation_segments']
        assert len(segs) == 2
        for first, last in segs:
            assert last > first
            centres = np.array([gt['frames'][i]['T_world_cam'] for i in range(first, last + 1)])
            assert np.array_equal(centres[:, :3, 3],
                                  np.repeat(centres[:1, :3, 3], len(centres), axis=0))
            angles = [np.arccos(np.clip((np.trace(a[:3, :3].T @ centres[0, :3, :3]) - 1) / 2,
                                        -1, 1)) for a in centres]
            assert max(angles) > np.deg2rad(5.0)
            assert all(gt['frames'][i]['pure_rotation'] for i in range(first, last + 1))
        moving = np.array([f['T_world_cam'] for f in gt['frames'] if not f['pure_rotation']])
        assert np.ptp(moving[:, :3, 3], axis=0).max() > 1.0


def test_trajectory_covers_the_papers_ranges() -> None:
    """Full-length paths reach the paper's distances: sheet up to ~7 m, cube up to 25 m."""
    for name, seed, far, near in (('outdoor_cube', 0, 19.0, 5.0), ('indoor_paper', 1, 3.0, 1.3)):
        sim = simulation.Simulation(simulation.SimConfig(name, seed, frames=450, width=320,
                                                         height=180))
        target = sim.trajectory.target_m
        d = [np.linalg.norm(sim.trajectory.pose(t)[:3, 3] - target)
             for t in np.linspace(0, 15.0, 200)]
        assert max(d) > far and min(d) < near
