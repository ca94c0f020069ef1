"""A cube face cut by the image border: its seen corners, and a pose from the seen part."""
from pathlib import Path
import sys

import numpy as np
import pytest

from absscale_ros.core import cube_border, cube_geometry, detect_cube, lines

sys.path.insert(0, str(Path(__file__).parent))
import synth_targets as st  # noqa: E402

# Cubes 4 m away pushed right until the border cuts one to three faces (yaw deg, offset px).
CUT = [(yaw, off) for yaw in (20, 35, 50) for off in (540, 580, 620, 660)]


def _cut_cube(yaw, off):
    R, t = st.cube_pose(yaw, 25, 4.0, offset_px=(off, 0))
    img, _, v_px = st.render_cube(np.random.default_rng(1), R, t)
    return img, v_px


def test_cube_cut_by_the_border_gives_its_seen_vertices_and_no_other():
    found = 0
    for yaw, off in CUT:
        img, v_px = _cut_cube(yaw, off)
        dets = detect_cube.detect_cubes(img, detect_cube.CubeConfig(), st.K)
        for d in dets:
            err = np.array([np.hypot(*(v_px - p).T).min() for p in d.vertices_px])
            assert err.max() < 1.0, (yaw, off, err)  # each a true vertex, to a pixel
            assert (d.vertices_px[:, 0] < 1280 - 2).all()  # none where the border cuts
        found += bool(dets)
    assert found >= 7  # (16 cube faces cut; without the cut faces: none of these)


def test_cut_faces_are_what_finds_those_cubes(monkeypatch):
    monkeypatch.setattr(detect_cube, '_border_side', lambda *a: None)
    # (nor faces cut across a corner: test_detect_cube_cut)
    monkeypatch.setattr(cube_border, 'border_quad', lambda *a, **k: None)
    assert not any(detect_cube.detect_cubes(_cut_cube(*c)[0], detect_cube.CubeConfig(), st.K)
                   for c in CUT)


@pytest.mark.parametrize('yaw, off', [(35, 600), (20, 560), (50, 640)])
def test_a_cut_face_completed_from_its_whole_side_is_the_true_face(yaw, off):
    """The two corners beyond the border follow from the whole side and the directions of
    the two sides leaving it (a square, known intrinsics)."""
    R, t = st.cube_pose(yaw, 25, 4.0, offset_px=(off, 0))
    _, faces, _ = st.render_cube(np.random.default_rng(1), R, t)
    tried = 0
    for _, corners, _ in faces:
        centre = corners.mean(axis=0)
        ls = np.array([lines.line_through(corners[k], corners[(k + 1) % 4], centre)
                       for k in range(4)])
        for cut in range(4):
            seen = corners.copy()  # the corners beyond the border: where a border cuts
            for far, near in ((cut, (cut + 3) % 4), ((cut + 1) % 4, (cut + 2) % 4)):
                seen[far] = corners[near] + 0.3 * (corners[far] - corners[near])
            done = cube_geometry.complete_cut(seen, ls, cut, st.K)
            assert done is not None
            np.testing.assert_allclose(done, corners, atol=1e-6)
            tried += 1
    assert tried >= 8


@pytest.mark.parametrize('blur_px', [16, 20])
def test_a_smeared_cut_face_poses_nothing(blur_px):
    """A motion streak across a cut face's sides shifts its seen corners, and the pose from it
    is an extrapolation: found sharp, the cube is not reported smeared (its cut faces mute,
    their sides ramping over more than ``cut_loose_ramp_px``)."""
    R, t = st.cube_pose(50, 25, 4.0, offset_px=(620, 0))
    cfg = detect_cube.CubeConfig()
    for blur, found in ((0, True), (blur_px, False)):
        img = st.render_cube(np.random.default_rng(1), R, t, blur_px=blur)[0]
        cut = [f for f in detect_cube._refine_faces(img, detect_cube.rough_faces(img, cfg), cfg)
               if f.cut >= 0]
        assert len(cut) == 2 and all(f.runs_on for f in cut) != found
        assert bool(detect_cube.detect_cubes(img, cfg, st.K)) == found
        assert found or all(f.ramp_px > cfg.cut_loose_ramp_px for f in cut)


@pytest.mark.parametrize('blur_px', [10, 12])
def test_smeared_cut_faces_pose_the_cube_when_no_sharp_face_does(blur_px):
    """Under a shorter streak the cut faces (no other face seen) ramp over 3.6-5 px: mute for
    a sharp pose, but they still pose the cube loosely, its two seen vertices within 3 px
    (the edges are ~180 px)."""
    R, t = st.cube_pose(50, 25, 4.0, offset_px=(620, 0))
    img, _, v_px = st.render_cube(np.random.default_rng(1), R, t, blur_px=blur_px)
    cfg = detect_cube.CubeConfig()
    cut = [f for f in detect_cube._refine_faces(img, detect_cube.rough_faces(img, cfg), cfg)
           if f.cut >= 0]
    assert len(cut) == 2 and any(f.runs_on for f in cut)
    dets = detect_cube.detect_cubes(img, cfg, st.K)
    assert len(dets) == 1 and len(dets[0].vertices_px) == 2
    assert max(np.hypot(*(v_px - p).T).min() for p in dets[0].vertices_px) < 3.0
    assert not detect_cube.detect_cubes(img, detect_cube.CubeConfig(cut_loose_ramp_px=0.0), st.K)
