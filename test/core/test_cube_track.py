"""
Cube detection frame after frame (``cube_track``, ``cube_hold``) on the outdoor sample bag's
frames.
"""
from dataclasses import replace
import json
from pathlib import Path

from absscale_ros import bagio, conversions
from absscale_ros.core import cube_hold, cube_track, detect, detect_cube, sfm_outputs, targets
import cv2
import numpy as np
import pytest

BAG = Path(__file__).parents[2] / 'bags' / 'outdoor_cube_sample.mcap'
CFG = detect_cube.CubeConfig()
SMALL = 20  # the cube at 0.29 % of the image: posed, under the paper's 0.5 %
SEEN = range(92, 140)  # the cube seen in every frame
LOST = 83  # the cube face-on, its top 3 px: no cube posed
# Frames 277 and 278 show the purple face whole and the red top as a strip wider than the strip
# search takes and too ragged for the face tests: no cube posed. Frame 276 found the cube.
FACE_SEEN = range(270, 280)
HELD = (277, 278)


@pytest.fixture(scope='module')
def frames() -> tuple[dict[int, np.ndarray], np.ndarray, dict]:
    gt = json.loads(Path(str(BAG) + '.gt.json').read_text())
    out = {}
    with bagio.open_bag(str(BAG)) as reader:
        for k, raw in enumerate(reader.messages([gt['bag']['image_topic']])):
            if k in (SMALL, LOST) or k in SEEN or k in FACE_SEEN:
                out[k] = conversions.compressed_msg_to_bgr(reader.deserialize(raw))
    return out, np.array(gt['camera']['K'], float), gt


def _errors(gt: dict, k: int, vertices_px: np.ndarray) -> np.ndarray:
    """Px from each vertex to the nearest true visible cube vertex of frame ``k``."""
    tf = gt['frames'][k]['targets'][0]
    true = np.array([v for v, seen in zip(tf['vertices_px'], tf['vertex_visible']) if seen])
    return np.hypot(*(true[None] - vertices_px[:, None]).transpose(2, 0, 1)).min(axis=1)


def test_tracked_cube_matches_the_whole_frame_search(frames) -> None:
    images, K, gt = frames
    tracker = cube_track.CubeTracker(CFG)
    diffs, err_whole, err_tracked = [], [], []
    for k in SEEN:
        whole = detect_cube.detect_cubes(images[k], CFG, K)
        tracked = tracker.detect(images[k], K)
        assert len(tracked) == len(whole) == 1, k
        a, b = whole[0], tracked[0]
        assert sorted(a.vertex_ids) == sorted(b.vertex_ids), k
        order_a, order_b = np.argsort(a.vertex_ids), np.argsort(b.vertex_ids)
        diffs.append(np.abs(a.vertices_px[order_a] - b.vertices_px[order_b]).max())
        err_whole += list(_errors(gt, k, a.vertices_px))
        err_tracked += list(_errors(gt, k, b.vertices_px))
    # Most frames are settled in the box; the whole frame every track_full_every frames.
    assert tracker.box_frames >= 0.6 * len(SEEN)
    assert tracker.whole_frames >= len(SEEN) // CFG.track_full_every
    # The box leaves out other objects' faces, which set how many profiles a side gets: the
    # vertices move by tenths of a pixel, as often nearer the truth as farther from it.
    assert np.median(diffs) < 0.3
    assert np.median(err_tracked) < np.median(err_whole) + 0.05
    assert np.percentile(err_tracked, 95) < np.percentile(err_whole, 95) + 0.2


def test_box_cutting_the_cube_finds_nothing(frames) -> None:
    images, K, _ = frames
    img = images[120]
    (det,) = detect_cube.detect_cubes(img, CFG, K)
    lo, hi = det.vertices_px.min(axis=0), det.vertices_px.max(axis=0)
    around = tuple(int(v) for v in (*(lo - 100), *(hi + 100)))
    assert len(detect_cube.detect_cubes(img, CFG, K, roi=around)) == 1
    cut = (around[0], around[1], int(0.5 * (lo[0] + hi[0])), around[3])
    assert detect_cube.detect_cubes(img, CFG, K, roi=cut) == []


def test_cube_under_the_paper_area_is_handed_on_not_reported(frames) -> None:
    images, K, _ = frames
    img = images[SMALL]
    small: list = []
    assert detect_cube.detect_cubes(img, CFG, K, small=small) == []
    (det,) = small
    area = sum(cv2.contourArea(p.astype(np.float32)) for _, p in det.polygons)
    assert area < CFG.small_cube_frac * CFG.min_area_frac * img.shape[0] * img.shape[1]
    # Without the shortcut the retries find nothing either; the tracker keeps a box on it.
    assert detect_cube.detect_cubes(img, detect_cube.CubeConfig(small_cube_frac=0.0), K) == []
    tracker = cube_track.CubeTracker(CFG)
    assert tracker.detect(img, K) == [] and tracker._box is not None


def test_resolution_change_drops_the_box(frames) -> None:
    """A box kept from a frame of another size (frame_ingest re-initialised) is not used: it
    may lie outside the new frame (cv2.error on an empty crop, the detector's process gone)."""
    images, K, _ = frames
    tracker = cube_track.CubeTracker(CFG)
    assert len(tracker.detect(images[120], K)) == 1 and tracker._box is not None
    crop = np.ascontiguousarray(images[121][:200, :300])
    assert tracker.detect(crop) == []
    h, w = images[121].shape[:2]
    third = cv2.resize(images[121], (w // 3, h // 3), interpolation=cv2.INTER_AREA)
    assert len(tracker.detect(third)) == 1
    with pytest.raises(ValueError):
        detect_cube.CubeConfig(small_cube_frac=1.5)


def test_box_showing_no_cube_waits_for_the_next_frame(frames) -> None:
    """Frame 83 shows the cube face-on with a 3 px top: nothing is posed in the box around
    frame 120's cube, nor in the whole frame. The tracker drops the box without searching the
    whole frame (``track_lost_wait``); the next frame is searched whole."""
    images, K, _ = frames
    assert detect_cube.detect_cubes(images[LOST], CFG, K) == []
    for wait in (True, False):
        cfg = replace(CFG, track_lost_wait=wait)
        tracker = cube_track.CubeTracker(cfg)
        assert len(tracker.detect(images[120], K)) == 1 and tracker._box is not None
        assert tracker.detect(images[LOST], K) == [] and tracker._box is None
        assert (tracker.lost_frames, tracker.whole_frames) == ((1, 1) if wait else (0, 2))
        assert len(tracker.detect(images[121], K)) == 1
        assert tracker.whole_frames == (2 if wait else 3)


def test_a_face_of_the_cube_found_a_frame_ago_is_reported(frames) -> None:
    images, K, gt = frames
    for k in HELD:  # alone, the frame poses no cube
        assert detect_cube.detect_cubes(images[k], CFG, K) == []
    for hold in (CFG.hold_frames, 0):
        tracker = cube_track.CubeTracker(replace(CFG, hold_frames=hold))
        found = {k: tracker.detect(images[k], K) for k in FACE_SEEN}
        assert found[276]
        if hold == 0:
            assert all(not found[k] for k in HELD)
            continue
        assert tracker.held_frames == len(HELD)
        for k in HELD:
            det, = found[k]
            assert [c for c, _ in det.polygons] == ['purple']
            assert len(det.vertices_px) == 4
            assert _errors(gt, k, det.vertices_px).max() < 1.0
            # the ids of the vertices that frame 276 found at those corners
            assert set(det.vertex_ids) <= set(found[276][0].vertex_ids)
            # reported on /absscale/vertices, but not confirmed as the cube: kept out of the map
            rows = detect.vertices_array(detect.FrameDetections((det, *found[276]), ('cube',)))
            assert (rows['score'] == targets.HELD_SCORE).sum() == 4
            mapped = sfm_outputs.vertices_from_rows(rows)
            assert len(mapped.points_px) == len(found[276][0].vertices_px)
            assert sfm_outputs.vertices_from_rows(detect.vertices_array(
                detect.FrameDetections((det,), ('cube',)))) is None


def test_a_face_that_changed_shape_or_place_is_not(frames) -> None:
    images, K, _ = frames
    last, = detect_cube.detect_cubes(images[276], CFG, K)
    faces: list[detect_cube.Face] = []
    detect_cube.detect_cubes(images[277], CFG, K, faces_out=faces)
    face, = [f for f in faces if f.colour == 'purple']
    corners = face.corners_px
    shape = images[277].shape
    det = cube_hold.held_face('purple', corners, last, 1, shape, CFG)
    assert det is not None
    # Listed from another corner or the other way round, each corner keeps its vertex's id
    # (a face matched to itself turned half way round swapped them; fresh outdoor 42).
    for other in (np.roll(corners, 2, axis=0), corners[::-1]):
        again = cube_hold.held_face('purple', other, last, 1, shape, CFG)
        ids = dict(zip(map(tuple, again.vertices_px), again.vertex_ids))
        assert ids == dict(zip(map(tuple, det.vertices_px), det.vertex_ids))
    assert cube_hold.held_face('purple', corners, last, CFG.hold_frames + 1, shape, CFG) is None
    assert cube_hold.held_face('yellow', corners, last, 1, shape, CFG) is None
    # A post moving over a tenth of the face: two corners 15 px inwards (the shape test lets
    # through about half that: 2 % of the side, the frame-to-frame change of a face seen whole).
    cut = corners.copy()
    cut[1:3] -= 0.1 * (corners[1] - corners[0])
    assert cube_hold.held_face('purple', cut, last, 1, shape, CFG) is None
    far = corners + [150.0, 0.0]  # the same shape where the cube was not
    assert cube_hold.held_face('purple', far, last, 1, shape, CFG) is None
    # Held frame after frame, a face may move as far as a face moves since the frame it was
    # last held in, not since the cube was found.
    side = float(np.hypot(*(corners - np.roll(corners, -1, axis=0)).T).max())
    moved = corners + [CFG.hold_shift_frac * side + 2.5 * CFG.hold_shift_px, 0.0]
    assert cube_hold.held_face('purple', moved, last, 3, shape, CFG) is not None
    assert cube_hold.held_face('purple', moved, last, 3, shape, CFG, moved=1) is None
