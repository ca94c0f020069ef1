"""Faces left out of the cube refinement by their measured colour step (``cube_prune``)."""
import json
from pathlib import Path

from absscale_ros import bagio, conversions
from absscale_ros.core import cube_prune, detect_cube
import numpy as np
import pytest

BAG = Path(__file__).parents[2] / 'bags' / 'outdoor_cube_sample.mcap'
FRAMES = (110, 190)  # blur retry: 5 faces ramp, one with a side under ``min_step``
CFG = detect_cube.CubeConfig()


@pytest.fixture(scope='module')
def images() -> dict[int, np.ndarray]:
    gt = json.loads(Path(str(BAG) + '.gt.json').read_text())
    with bagio.open_bag(str(BAG)) as reader:
        return {k: conversions.compressed_msg_to_bgr(reader.deserialize(raw))
                for k, raw in enumerate(reader.messages([gt['bag']['image_topic']]))
                if k in FRAMES}


def _key(faces: list) -> list:
    return [None if f is None else (f.colour, f.corners_px.tobytes(), f.lines.tobytes(),
                                    f.supports.tobytes(), f.cut, f.outside, f.runs_on)
            for f in faces]


@pytest.mark.parametrize('k', FRAMES)
def test_pruned_faces_change_no_other_face(images, k, monkeypatch) -> None:
    img = images[k]
    rough = detect_cube.rough_faces(img, CFG)
    kept = []
    orig = cube_prune.steps_pass

    def counted(*args):
        kept.append(orig(*args))
        return kept[-1]
    monkeypatch.setattr(cube_prune, 'steps_pass', counted)
    pruned = detect_cube._refine_each(img, rough, CFG, 12.0)
    assert len(kept) == 1 and 0 < kept[0].sum() < len(kept[0])  # some faces left out
    monkeypatch.setattr(cube_prune, 'steps_pass',
                        lambda colours, real, m: np.ones(len(real), bool))
    every = detect_cube._refine_each(img, rough, CFG, 12.0)
    # Every face refined: the same faces, bit for bit; the pruned ones fail the step test.
    assert _key(pruned) == _key(every)
    assert all(f is None for f, keep in zip(pruned, kept[0]) if not keep)
    assert sum(f is not None for f in pruned) >= 2


def test_steps_pass_skips_border_sides() -> None:
    inside = np.full((8, 3), 200.0, np.float32)
    outside = inside - 20.0  # step 34.6 on every side ...
    outside[1] = inside[1] - 5.0  # ... but 8.7 on face 0's side 1 and face 1's side 2
    outside[6] = inside[6] - 5.0
    real = np.ones((2, 4), bool)
    assert cube_prune.steps_pass((inside, outside), real, 15.0).tolist() == [False, False]
    real[1, 2] = False  # face 1's side 2 runs along the image border: no step there
    assert cube_prune.steps_pass((inside, outside), real, 15.0).tolist() == [False, True]
