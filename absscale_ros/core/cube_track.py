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
slowest frames of a video. A frame where nothing is found but one whole face the cube
detected in the last ``hold_frames`` frames had, moved as a face moves (from the frame
before, when that frame reported it so), reports that face (``cube_hold``), or failing that
the seen corners of one such face a post or the border cuts along one side.
"""
import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import cube_hold, detect_cube, targets

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
        self._last: list[targets.TargetDetection] = []  # the cubes last detected ...
        self._age = 0  # ... this many frames ago
        self._moved = 0  # frames since ``_last`` was set (a held face's: since that frame)
        self.box_frames = self.whole_frames = self.lost_frames = self.held_frames = 0

    def detect(self, image_bgr: npt.NDArray[np.uint8], K: Array | None = None,
               half: npt.NDArray[np.uint8] | None = None) -> list[targets.TargetDetection]:
        """Return ``detect_cubes`` of this frame (``image_bgr`` (H, W, 3) uint8 BGR), or a
        face the cube last detected had (``cube_hold``)."""
        if image_bgr.shape[:2] != self._shape:  # a new resolution: the box is of another frame
            self._box, self._shape, self._last = None, image_bgr.shape[:2], []
        faces: list[detect_cube.Face] = []
        small: list[targets.TargetDetection] = []
        out = self._search(image_bgr, K, half, faces, small)
        if out:
            self._last, self._age, self._moved = out, 0, 0
            return out
        self._age += 1
        self._moved += 1
        if small:
            return out  # the cube posed, too small to report: no face of it either
        out = self._held(faces, image_bgr.shape)
        if out:
            # The next frame's face is matched to this one (a frame's motion), while the
            # frames are still counted from the cube's.
            self._last, self._moved = out, 0
            self.held_frames += 1
        return out

    def _held(self, faces: list[detect_cube.Face], shape: tuple[int, ...]
              ) -> list[targets.TargetDetection]:
        """Return the first whole face of ``faces`` that ``cube_hold`` finds a face of the
        cubes last detected had, else the first face cut along one side (by a post or the
        border) it so finds, as a detection (none when there is none)."""
        cfg = self._cfg
        min_area = cfg.min_area_frac * shape[0] * shape[1]
        big = [f for f in faces if not (f.thin or f.outside >= 0 or f.seen) and
               abs(cv2.contourArea(f.corners_px.astype(np.float32))) >= min_area]
        for f in big:
            if f.runs_on or f.cut >= 0:
                continue
            for last in self._last:
                det = cube_hold.held_face(f.colour, f.corners_px, last, self._age, shape, cfg,
                                          self._moved)
                if det is not None:
                    return [det]
        for f in big if cfg.hold_cut_ramp_px > 0.0 else ():
            # (its seen sides sharp enough to fix its two seen corners)
            if f.cut < 0 or f.ramp_px > cfg.hold_cut_ramp_px:
                continue
            for last in self._last:
                det = cube_hold.held_cut_face(f.colour, f.corners_px, f.cut, last, self._age,
                                              shape, cfg, self._moved)
                if det is not None:
                    return [det]
        return []

    def _search(self, image_bgr: npt.NDArray[np.uint8], K: Array | None,
                half: npt.NDArray[np.uint8] | None, faces: list[detect_cube.Face],
                small: list[targets.TargetDetection]) -> list[targets.TargetDetection]:
        """Return ``detect_cubes`` of this frame in the box or whole; the sharp pass's faces
        of the search that settled the frame are added to ``faces``, a cube too small to
        report to ``small``."""
        cfg = self._cfg
        if self._box is not None and self._since_full + 1 < cfg.track_full_every:
            posed: list[targets.TargetDetection] = []
            out = detect_cube.detect_cubes(image_bgr, cfg, K, half, self._box, small, posed,
                                           faces)
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
            faces.clear()
        out = detect_cube.detect_cubes(image_bgr, cfg, K, half, small=small, faces_out=faces)
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
