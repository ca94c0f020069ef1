"""
The aspect evidence of the rectangles a video showed in its last frames, for the sheet detector.

A sheet's aspect test allows the ratio change that corner noise causes in one frame (and a
floor for lens and paper cut). A rectangle of a nearby aspect (a 4:3 board is 3 % off letter)
passes it in the odd frame where the noise pulls its corners towards the sheet's; over the
frames it is seen, its error stays above the tolerance. Noise does not persist: a rectangle
whose aspect error over its tolerance has a median above one over the frames it was measured
in is not reported in the frame where it passes. The rectangles are followed from frame to
frame by their image position and size (``MATCH_CENTRE``, ``MATCH_SIZE``). The history also
keeps which hidden-corner path found the last frame's sheet, for the detector to try first.
"""
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]
MATCH_CENTRE = 0.25  # of a rectangle's diagonal: how far its centre may move between frames
MATCH_SIZE = 1.4  # the factor its diagonal may grow or shrink by between frames
MATCH_GAP = 2  # frames a rectangle may go unmeasured and still be followed


@dataclass
class _Track:
    centre: Array
    diagonal: float
    last: int
    ratios: dict[int, float] = field(default_factory=dict)  # frame -> smallest error / tol


class SheetHistory:
    """
    The rectangles measured by the aspect test in the last frames of one video, in order.

    ``next_frame`` starts a frame; ``note`` adds a whole rectangle's aspect error over its
    tolerance (``sheet_checks.passes``); ``refuted`` says whether the rectangle's earlier frames
    outvote this frame's pass. ``hidden_path`` is the hidden-corner path that found the last
    frame's sheet (``detect_sheet.HIDDEN_PATHS``; None: none), which the next frame tries
    first (``detect_sheet._accept_hidden``).
    """

    def __init__(self) -> None:
        self._frame = 0
        self._tracks: list[_Track] = []
        self.hidden_path: str | None = None

    def next_frame(self, window: int) -> None:
        """Start the next frame; forget rectangles not measured in the last ``window`` frames."""
        self._frame += 1
        self._tracks = [t for t in self._tracks if self._frame - t.last <= window]
        for t in self._tracks:  # (a page followed for minutes: only the window counts)
            t.ratios = {k: r for k, r in t.ratios.items() if self._frame - k <= window}

    def note(self, corners: Array, ratio: float) -> None:
        """Add this frame's aspect error over its tolerance of the rectangle ``corners``
        (4, 2) px (several outlines of one rectangle in a frame: the smallest)."""
        track = self._match(corners)
        centre, diagonal = _shape(corners)
        if track is None:
            self._tracks.append(_Track(centre, diagonal, self._frame, {self._frame: ratio}))
            return
        track.centre, track.diagonal, track.last = centre, diagonal, self._frame
        track.ratios[self._frame] = min(ratio, track.ratios.get(self._frame, np.inf))

    def refuted(self, corners: Array, window: int, min_frames: int) -> bool:
        """
        Return True when the rectangle ``corners`` (noted in this frame) was measured in at
        least ``min_frames`` of the last ``window`` frames before this one and the median
        of its errors over their tolerance, this frame's included, is above one.
        """
        track = self._match(corners)
        if track is None:
            return False
        before = [r for k, r in track.ratios.items() if self._frame - window <= k < self._frame]
        if len(before) < min_frames:
            return False
        return bool(np.median(before + [track.ratios.get(self._frame, 0.0)]) > 1.0)

    def _match(self, corners: Array) -> _Track | None:
        """The track nearest ``corners`` within the matching tolerances, or None."""
        centre, diagonal = _shape(corners)
        best, best_d = None, np.inf
        for t in self._tracks:
            if self._frame - t.last > MATCH_GAP or not \
                    1.0 / MATCH_SIZE <= diagonal / max(t.diagonal, 1e-9) <= MATCH_SIZE:
                continue
            d = float(np.hypot(*(centre - t.centre)))
            if d <= MATCH_CENTRE * diagonal and d < best_d:
                best, best_d = t, d
        return best


def _shape(corners: Array) -> tuple[Array, float]:
    """Centre (2,) px and bounding-box diagonal px of a quadrilateral (4, 2) px."""
    return corners.mean(axis=0), float(np.hypot(*(corners.max(axis=0) - corners.min(axis=0))))
