"""
Cube faces seen edge-on (strips) on simulator frames: the outline drawn for the top must lie
on the top. On 4/154 the cube posed on a face seen nearly square-on put the strip's far
corners ~15 px along its side (65 % of the red drawn lay on the top). On 70o/159 a red box
behind the cube gave a red strip along the far side of the yellow face (a side face: the face
across from it is purple), and its profiles behind the top tilted the top's width line from 7
px at both ends to 0 and 23 px (27 % on the top).
"""
from pathlib import Path
import sys

import numpy as np
import pytest

from absscale_ros.core import cube_strips
from absscale_ros.tools import bench_detect

sys.path.insert(0, str(Path(__file__).parent))
import sim_cube_frames  # noqa: E402

FOLDER = 'sim_cube_strips'
SHAPE = (720, 1280)


def _top_precision(fr, dets) -> tuple[float, int]:
    """Return (share of the top colour's drawn pixels on the true top, those pixels)."""
    colour = fr['variant']['top_colour']
    # Of the two faces of that colour, the top is the higher in the image (seen from above).
    quads = [np.array([fr['vertices_px'][v] for v in f['vertex_ids']]) for f in fr['faces']
             if f['colour'] == colour]
    truth = bench_detect._poly_mask(SHAPE, min(quads, key=lambda q: q[:, 1].mean())) > 0
    drawn = np.zeros(SHAPE, bool)
    for d in dets:
        for lab, poly in d.polygons:
            if lab == colour:
                drawn |= bench_detect._poly_mask(SHAPE, poly) > 0
    n = int(drawn.sum())
    return (drawn & truth).sum() / max(n, 1), n


@pytest.mark.parametrize('name', sorted(sim_cube_frames.frames(FOLDER)))
def test_top_strip_lies_on_the_top(name):
    fr, dets = sim_cube_frames.cubes(FOLDER, name)
    assert len(dets) == 1, fr['what']
    precision, drawn = _top_precision(fr, dets)
    assert drawn > 300, fr['what']  # the top is drawn
    assert precision > 0.85, fr['what']


def test_a_box_behind_part_of_the_top_does_not_widen_it():
    # With one width line through all of the top's profiles, the 6 that run on into the red
    # box behind tilt it to a wedge (0 to 23 px where the top is ~7 px wide).
    fr, dets = sim_cube_frames.cubes(FOLDER, 'outdoor_cube_70o_159.jpg', strip_width_tol_px=0.0)
    assert _top_precision(fr, dets)[0] < 0.6


def test_width_line_leaves_out_only_profiles_wider_than_it():
    """``_width_line``: the profiles off the line most lie on are left out when they are all
    wider (a box of the strip's colour behind part of it), not when some are narrower (a
    box only lengthens them; then all count)."""
    t = (np.arange(16) + 0.5) / 16
    boxed = np.where(t < 0.6, 5.0, 12.0)  # the last 6 run on into a box behind
    assert np.allclose(cube_strips._width_line(t, boxed, 1.5), (5.0, 5.0))
    narrow = np.full(16, 5.0)
    narrow[[1, 4, 7, 10, 13, 15]] = 1.0  # 6 narrower ones: no box, all of them count
    assert max(cube_strips._width_line(t, narrow, 1.5)) < 4.0
    assert not np.allclose(cube_strips._width_line(t, boxed, 0.0),
                           (5.0, 5.0))  # tol 0: through all of them
