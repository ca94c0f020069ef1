"""
Target detection front end: which detectors to run, and one result per frame.

``target`` selects a sheet ('letter', 'a4', 'custom'), any configured sheet size ('sheet': a
user's page may be letter or A4), the cube, or 'auto' (every sheet size configured plus the
cube), so one frame can report several targets of several kinds.
"""
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import cube_track, detect_cube, detect_sheet, sheet_track, targets

TARGET_CHOICES = ('letter', 'a4', 'custom', 'sheet', 'cube', 'auto')


@dataclass(frozen=True)
class DetectConfig:
    """
    What to look for.

    :param target: one of ``TARGET_CHOICES``.
    :param auto_sheets: sheet names tried in 'sheet' and 'auto' modes, in one search (each
        detection is named after the size its aspect fits best: A4 and letter differ by 9 %).
    :param sheet: the sheet detector's thresholds (its ``sheet`` field is set from ``target``).
    :param cube: the cube detector's thresholds.
    """

    target: str = 'auto'
    auto_sheets: tuple[str, ...] = ('letter', 'a4')
    sheet: detect_sheet.SheetConfig = field(default_factory=detect_sheet.SheetConfig)
    cube: detect_cube.CubeConfig = field(default_factory=detect_cube.CubeConfig)

    def __post_init__(self) -> None:
        if self.target not in TARGET_CHOICES:
            raise ValueError(f'target must be one of {TARGET_CHOICES}, got {self.target!r}')
        for name in self.auto_sheets:
            targets.sheet_model(name)  # raises ValueError on an unknown sheet

    def sheet_configs(self) -> list[detect_sheet.SheetConfig]:
        """Return the sheet detector configurations this target setting runs."""
        if self.target == 'cube':
            return []
        if self.target in ('sheet', 'auto'):
            if not self.auto_sheets:
                return []
            return [replace(self.sheet, sheet=self.auto_sheets[0],
                            other_sheets=self.auto_sheets[1:])]
        return [replace(self.sheet, sheet=self.target)]


@dataclass(frozen=True, eq=False)
class FrameDetections:
    """
    Every target found in one frame.

    :param detections: found targets, ``object_id`` = index in this tuple.
    :param looked_for: target kinds searched ('sheet', 'cube').
    """

    detections: tuple[targets.TargetDetection, ...]
    looked_for: tuple[str, ...]

    @property
    def kinds(self) -> tuple[str, ...]:
        """Target kinds seen in this frame, sorted, without repeats."""
        return tuple(sorted({d.target_type for d in self.detections}))


def detect(image_bgr: npt.NDArray[np.uint8], cfg: DetectConfig,
           K: npt.NDArray[np.float64] | None = None,
           dist: npt.NDArray[np.float64] | None = None,
           tracker: cube_track.CubeTracker | None = None,
           sheet_history: sheet_track.SheetHistory | None = None) -> FrameDetections:
    """
    Run the configured detectors on one BGR image.

    :param image_bgr: (H, W, 3) uint8 BGR image (distorted is fine: edges are fitted locally).
    :param K: (3, 3) intrinsics px, used by the sheet aspect and cube shape checks; None to
        estimate.
    :param dist: OpenCV distortion coefficients (CameraInfo D), used with ``K`` by the sheet
        aspect check; None for none.
    :param tracker: for frames of one video in order: the cube searched first around where the
        last frame showed it (``cube_track``; made with ``cfg.cube``); None: the whole frame.
    :param sheet_history: for frames of one video in order: the aspect errors of the
        rectangles the sheet detector measured in the last frames (``sheet_track``); None:
        each frame alone.
    """
    if image_bgr.ndim != 3 or image_bgr.shape[2] != 3 or image_bgr.dtype != np.uint8:
        raise ValueError(f'need an (H, W, 3) uint8 image, got {image_bgr.shape} {image_bgr.dtype}')
    found: list[targets.TargetDetection] = []
    looked: list[str] = []
    sheet_cfgs = cfg.sheet_configs()
    half = None
    if cfg.target == 'auto':  # both detectors start from the image box-filtered to half size
        h, w = image_bgr.shape[:2]
        half = cv2.resize(image_bgr, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
    if cfg.target in ('cube', 'auto'):
        looked.append('cube')
        found += detect_cube.detect_cubes(image_bgr, cfg.cube, K, half) if tracker is None \
            else tracker.detect(image_bgr, K, half)
    if sheet_cfgs:
        looked.append('sheet')
    for sheet_cfg in sheet_cfgs:
        for det in detect_sheet.detect_sheets(image_bgr, sheet_cfg, K, half, dist,
                                              sheet_history):
            if not any(_same_sheet(det, d) for d in found):
                found.append(det)
    found = [replace(d, object_id=i) for i, d in enumerate(found)]
    return FrameDetections(tuple(found), tuple(looked))


def _same_sheet(a: targets.TargetDetection, b: targets.TargetDetection) -> bool:
    """Return True when two sheet detections outline the same quadrilateral."""
    if a.target_type != 'sheet' or b.target_type != 'sheet':
        return False
    return bool(np.abs(a.vertices_px - b.vertices_px).max() < 4.0)


def detection_to_dict(det: targets.TargetDetection) -> dict[str, object]:
    """Return a JSON-ready dict of one detection (pixel coordinates, ids, edges)."""
    return {
        'object_id': det.object_id,
        'target_type': det.target_type,
        'name': det.name,
        'score': round(det.score, 4),
        'vertices': [{'id': int(i), 'u_px': round(float(u), 3), 'v_px': round(float(v), 3),
                      'score': round(float(sc), 4)}
                     for i, (u, v), sc in zip(det.vertex_ids, det.vertices_px, det.scores())],
        'edges': [[int(a), int(b)] for a, b in det.edges],
    }


# One row per vertex; the layout of the /absscale/vertices PointCloud2 (see docs/topics.md).
VERTEX_DTYPE = np.dtype([('u', '<f4'), ('v', '<f4'), ('vertex_id', '<i4'), ('object_id', '<i4'),
                         ('target_type', '<i4'), ('edge_mask', '<i4'), ('score', '<f4')])


def vertices_array(result: FrameDetections) -> npt.NDArray[np.void]:
    """
    Return every vertex of a frame as a (N,) ``VERTEX_DTYPE`` structured array (N may be 0).

    ``edge_mask`` bit j is set when the vertex shares an image edge with the j-th vertex of the
    same object in this array's order; ``target_type`` is ``targets.TARGET_TYPE_CODES``.
    """
    rows = []
    for d in result.detections:
        n = len(d.vertices_px)
        masks = np.zeros(n, dtype=np.int64)
        for a, b in d.edges:
            masks[a] |= 1 << int(b)
            masks[b] |= 1 << int(a)
        block = np.zeros(n, dtype=VERTEX_DTYPE)
        block['u'], block['v'] = d.vertices_px[:, 0], d.vertices_px[:, 1]
        block['vertex_id'], block['object_id'] = d.vertex_ids, d.object_id
        block['target_type'] = targets.TARGET_TYPE_CODES[d.target_type]
        block['edge_mask'], block['score'] = masks, d.scores()
        rows.append(block)
    return np.concatenate(rows) if rows else np.zeros(0, dtype=VERTEX_DTYPE)


_OVERLAY_BGR = {'sheet': (255, 255, 0), 'red': (0, 0, 255), 'yellow': (0, 255, 255),
                'purple': (255, 0, 200)}


def draw_overlay(image_bgr: npt.NDArray[np.uint8], result: FrameDetections
                 ) -> npt.NDArray[np.uint8]:
    """Return a copy of the image with outlines, vertices and their ids drawn."""
    out = image_bgr.copy()
    for d in result.detections:
        for label, poly in d.polygons:
            pts = np.round(poly * 16).astype(np.int32).reshape(-1, 1, 2)
            cv2.polylines(out, [pts], True, _OVERLAY_BGR.get(label, (0, 255, 0)), 2,
                          cv2.LINE_AA, shift=4)
        for (u, v), vid, sc in zip(d.vertices_px, d.vertex_ids, d.scores()):
            # A filled dot for a seen vertex, a ring for an extrapolated one (score <= 0.5).
            cv2.circle(out, (int(round(u)), int(round(v))), 4, (0, 255, 0),
                       -1 if sc > 0.5 or sc >= d.score else 2)
            cv2.putText(out, f'{d.object_id}:{vid}', (int(u) + 5, int(v) - 5),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 255, 0), 1, cv2.LINE_AA)
    return out
