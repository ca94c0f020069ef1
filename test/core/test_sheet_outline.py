"""The seen outline of a sheet a box stands on (``sheet_partial.clipped`` and ``snapped``)."""
import cv2
from absscale_ros.core import sheet_partial, sheet_stub
import numpy as np
import pytest

QUAD = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 100.0], [0.0, 100.0]])  # corner 3 hidden
# The part seen: the sheet less a 40 x 40 px box over corner 3, its outline half a pixel in.
SEEN = np.array([[0.5, 0.5], [99.5, 0.5], [99.5, 99.5], [40.0, 99.5], [40.0, 60.0], [0.5, 60.0]])


def _area(poly: np.ndarray) -> float:
    return cv2.contourArea(poly.astype(np.float32))


@pytest.mark.parametrize('turn', [1, -1])
def test_clipped_cuts_the_hidden_corner_off_along_the_box(turn) -> None:
    # Either way round the region's outline: the corners kept are the three seen ones.
    region = sheet_stub.dense(SEEN[::turn])
    out = sheet_partial.clipped(QUAD, region)
    assert abs(_area(out) - 100.0 * 100.0 + 40.0 * 40.0) < 1.0
    assert not (np.abs(out - QUAD[3]).sum(axis=1) < 1.0).any()
    for corner in QUAD[:3]:
        assert (np.abs(out - corner).sum(axis=1) < 1e-9).any()
    # the box's edge meets sides 2 and 3 at (40, 100) and (0, 60)
    ends = {tuple(np.round(out[0], 6)), tuple(np.round(out[-4], 6))}
    assert ends == {(40.0, 100.0), (0.0, 60.0)}


def test_clipped_needs_an_occluder_edge_inside() -> None:
    whole = sheet_stub.dense(np.array([[0.5, 0.5], [99.5, 0.5], [99.5, 99.5], [0.5, 99.5]]))
    assert sheet_partial.clipped(QUAD, whole) is None


def test_snapped_puts_the_seen_outline_on_the_sides() -> None:
    out = sheet_partial.snapped(QUAD, sheet_stub.dense(SEEN))
    assert abs(_area(out) - 100.0 * 100.0 + 40.0 * 40.0) < 1e-6
    for corner in QUAD[:3]:
        assert (np.abs(out - corner).sum(axis=1) < 1e-9).any()
