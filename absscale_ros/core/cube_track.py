"""
Cube detection frame after frame: first around where the last frame showed the cube.

From one frame to the next a cube moves a few tens of pixels: the mask stage, the refinement
and the strip search over the whole frame mostly handle other objects of the cube colours.
While the last frame showed a cube (or one too small to report: ``small_cube_frac``),
``CubeTracker`` looks only in a box around it
(``detect_cube.detect_cubes(roi=...)``), and searches the whole frame whenever that finds
nothing (the cube left the box, or came near its edge, or a colour region reaching the edge
comes near it) and at least every ``track_full_every`` frames, so that a cube coming into view
beside the tracked one is found within that many frames. When the box shows no cube at all
(``track_lost_wait``), the whole frame is searched at the next frame instead: such a frame
mostly shows the cube hidden or too oblique, where a whole search (the sharp pass, then the
split and blur retries on every region of the frame) cost the box's ~5 ms plus ~20 ms, the
slowest frames of a video.
"""
import numpy as np
import numpy.typing as npt

from absscale_ros.core import detect_cube, targets

Array = npt.NDArray[np.float64]


class CubeTracker:
    """
    ``detect_cube.detect_cubes`` with a search box kept from frame to frame; ``box_frames``,
    ``whole_frames`` and ``lost_frames`` count the frames settled in the box, those searched
    whole and those whose box showed no cube (``track_lost_wait``: not searched whole).
    """

    def __init__(self, cfg: detect_cube.CubeConfig) -> None:
        self._cfg = cfg
        self._box: tuple[int, int, int, int] | None = None  # full px, x0 y0 x1 y1
        self._shape: tuple[int, ...] = ()  # (H, W) of the frame the box was found in
        self._since_full = 0
        self.box_frames = self.whole_frames = self.lost_frames = 0

    def detect(self, image_bgr: npt.NDArray[np.uint8], K: Array | None = None,
               half: npt.NDArray[np.uint8] | None = None) -> list[targets.TargetDetection]:
        """Return ``detect_cubes`` of this frame (``image_bgr`` (H, W, 3) uint8 BGR)."""
        cfg = self._cfg
        small: list[targets.TargetDetection] = []
        if image_bgr.shape[:2] != self._shape:  # a new resolution: the box is of another frame
            self._box, self._shape = None, image_bgr.shape[:2]
        if self._box is not None and self._since_full + 1 < cfg.track_full_every:
            posed: list[targets.TargetDetection] = []
            out = detect_cube.detect_cubes(image_bgr, cfg, K, half, self._box, small, posed)
            if out or small:
                self._since_full += 1
                self.box_frames += 1
                self._box = self._search_box(out or small, image_bgr.shape)
                return out
            if not posed and cfg.track_lost_wait:
                # No cube in the box at all: lost, not moved out of it (on the tuning bags the
                # whole frame then found one in 1 of 31 frames): the next frame searches whole.
                self._box = None
                self.lost_frames += 1
                return out
        out = detect_cube.detect_cubes(image_bgr, cfg, K, half, small=small)
        self._since_full = 0
        self.whole_frames += 1
        self._box = self._search_box(out or small, image_bgr.shape) if out or small else None
        return out

    def _search_box(self, found: list[targets.TargetDetection], shape: tuple[int, ...]
                    ) -> tuple[int, int, int, int] | None:
        """The box around every cube found, grown by the margins; None when it is most of
        the frame (the whole frame is searched then)."""
        lo, hi = detect_cube.extent(found)
        grow = self._cfg.track_margin_frac * float((hi - lo).max()) + self._cfg.track_margin_px
        h, w = shape[:2]
        x0, y0 = int(max(0.0, lo[0] - grow)), int(max(0.0, lo[1] - grow))
        x1, y1 = int(min(w, hi[0] + grow + 1)), int(min(h, hi[1] + grow + 1))
        if (x1 - x0) * (y1 - y0) > self._cfg.track_max_area_frac * w * h:
            return None
        return x0, y0, x1, y1
