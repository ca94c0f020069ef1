"""
``absscale bench detect BAG...``: detection accuracy and speed against the simulator's gt.json.

Per frame: face / sheet pixel precision and recall (the paper's eq. 10-11, pixels pooled over
all frames; true pixels are those of targets covering >= 0.5% of the image, so a smaller
target that is reported counts as false positives), corner error as delta / l (Table 2: l is
the longer image edge at the vertex) and in px, detection rate over frames where a target
covers >= 0.5% of the image, frames with vertices although no target is visible, and time per
frame (decode excluded; one OpenCV thread unless --threads). Prints a table shaped like the
paper's Table 2 with the paper's figures beside ours.
"""
import argparse
import json
import time
from typing import Any

import cv2
import numpy as np

from absscale_ros import bagio, conversions
from absscale_ros.core import detect

LABELS = ('red', 'yellow', 'purple', 'sheet')
# The paper's Table 2: precision %, recall %, corner error delta / l.
PAPER = {'red': (92.1, 90.8), 'yellow': (96.5, 94.1), 'purple': (91.8, 89.9),
         'sheet': (98.3, 92.1), 'cube_err': 0.03, 'sheet_err': 0.01}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bags', nargs='+', metavar='BAG', help='bags with BAG.gt.json beside')
    parser.add_argument('--target', default='from-gt',
                        choices=('from-gt',) + detect.TARGET_CHOICES,
                        help='detector target (default: the bag scene variant target)')
    parser.add_argument('--max-frames', type=int, default=0, help='frames per bag (0 = all)')
    parser.add_argument('--json', action='store_true', help='print the figures as JSON')
    parser.add_argument('--threads', type=int, default=1,
                        help='OpenCV threads while timing (default 1: one core; 0 = leave as is)')


def _mask(shape: tuple[int, int], rings: list[Any], holes: list[Any]) -> np.ndarray:
    m = np.zeros(shape, np.uint8)
    if rings:
        cv2.fillPoly(m, [np.asarray(r, np.int32).reshape(-1, 1, 2) for r in rings], 1)
    if holes:
        cv2.fillPoly(m, [np.asarray(r, np.int32).reshape(-1, 1, 2) for r in holes], 0)
    return m


def _poly_mask(shape: tuple[int, int], poly_px: np.ndarray) -> np.ndarray:
    """Pixels whose centre lies inside a float polygon (8 fractional bits)."""
    m = np.zeros(shape, np.uint8)
    cv2.fillPoly(m, [np.round(poly_px * 256).astype(np.int32).reshape(-1, 1, 2)], 1,
                 lineType=cv2.LINE_8, shift=8)
    return m


class Tally:
    """Accumulates the figures over frames and bags."""

    def __init__(self) -> None:
        self.tp = dict.fromkeys(LABELS, 0)
        self.fp = dict.fromkeys(LABELS, 0)
        self.fn = dict.fromkeys(LABELS, 0)
        self.rel = {'cube': [], 'sheet': []}  # type: dict[str, list[float]]
        self.px = {'cube': [], 'sheet': []}  # type: dict[str, list[float]]
        self.eligible = self.detected = self.empty = self.false_frames = 0
        self.times_ms: list[float] = []

    def pixels(self, label: str, truth: np.ndarray, found: np.ndarray) -> None:
        self.tp[label] += int(np.count_nonzero(truth & found))
        self.fp[label] += int(np.count_nonzero(found & ~truth))
        self.fn[label] += int(np.count_nonzero(truth & ~found))


def _frame(gt: dict[str, Any], fr: dict[str, Any], res: detect.FrameDetections,
           shape: tuple[int, int], tally: Tally) -> None:
    truth = {lab: np.zeros(shape, bool) for lab in LABELS}
    found = {lab: np.zeros(shape, bool) for lab in LABELS}
    visible = eligible = hit = False
    for tf in fr['targets']:
        tm = gt['targets'][tf['id']]
        colours = {f['id']: f['colour'] for f in tm['faces']}
        visible |= tf['area_fraction'] > 0.0
        if not tf['covers_min_area']:
            continue  # must be rejected: its pixels count as false positives if found
        for face in tf['faces']:
            lab = 'sheet' if tm['kind'] == 'sheet' else colours[face['id']]
            truth[lab] |= _mask(shape, face['polygons_px'], face.get('holes_px') or []) > 0
        eligible = True
        hit |= _corners(tm, tf, res, tally)
    for d in res.detections:
        for lab, poly in d.polygons:
            found[lab] |= _poly_mask(shape, poly) > 0
    for lab in LABELS:
        tally.pixels(lab, truth[lab], found[lab])
    tally.eligible += eligible
    tally.detected += eligible and hit
    if not visible:
        tally.empty += 1
        tally.false_frames += bool(res.detections)


def _corners(tm: dict[str, Any], tf: dict[str, Any], res: detect.FrameDetections,
             tally: Tally) -> bool:
    """Match visible true vertices to detected ones of the same kind; record errors."""
    kind = tm['kind']
    dets = [d for d in res.detections if d.target_type == kind]
    if not dets:
        return False
    found = np.concatenate([d.vertices_px for d in dets])
    true = np.array([v if v is not None else [np.nan, np.nan] for v in tf['vertices_px']], float)
    hit = False
    for i, vis in enumerate(tf['vertex_visible']):
        if not vis:
            continue
        nbrs = [b if a == i else a for a, b in tm['edges'] if i in (a, b)]
        lens = [np.hypot(*(true[j] - true[i])) for j in nbrs if np.isfinite(true[j]).all()]
        length = max(lens) if lens else np.nan
        err = np.hypot(*(found - true[i]).T).min()
        if np.isfinite(length) and err < 0.1 * length:  # a match, not another vertex
            tally.rel['cube' if kind == 'cube' else 'sheet'].append(err / length)
            tally.px['cube' if kind == 'cube' else 'sheet'].append(err)
            hit = True
    return hit


def bench_bag(path: str, target: str, max_frames: int, tally: Tally) -> None:
    with open(path + '.gt.json') as f:
        gt = json.load(f)
    if target == 'from-gt':
        target = gt['scene']['variant']['target']
    K = np.array(gt['camera']['K'], float)
    cfg = detect.DetectConfig(target=target)
    topic = gt['bag']['image_topic']
    with bagio.open_bag(path) as reader:
        for k, bm in enumerate(reader.messages([topic])):
            if max_frames and k >= max_frames:
                break
            msg = reader.deserialize(bm)
            compressed = bm.msgtype.endswith('CompressedImage')
            img = (conversions.compressed_msg_to_bgr(msg) if compressed
                   else conversions.image_msg_to_bgr(msg))
            t0 = time.perf_counter()
            res = detect.detect(img, cfg, K)
            tally.times_ms.append(1e3 * (time.perf_counter() - t0))
            _frame(gt, gt['frames'][k], res, img.shape[:2], tally)


def figures(t: Tally) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for lab in LABELS:
        det, true = t.tp[lab] + t.fp[lab], t.tp[lab] + t.fn[lab]
        out[lab] = {'precision_pct': 100.0 * t.tp[lab] / det if det else None,
                    'recall_pct': 100.0 * t.tp[lab] / true if true else None,
                    'true_px': true}
    for kind in ('cube', 'sheet'):
        r, p = np.array(t.rel[kind]), np.array(t.px[kind])
        out[kind + '_corner'] = {'n': len(r),
                                 'median_rel': float(np.median(r)) if len(r) else None,
                                 'mean_rel': float(r.mean()) if len(r) else None,
                                 'median_px': float(np.median(p)) if len(p) else None,
                                 'p95_px': float(np.percentile(p, 95)) if len(p) else None}
    times = np.array(t.times_ms) if t.times_ms else np.array([np.nan])
    out['detection_rate_pct'] = 100.0 * t.detected / t.eligible if t.eligible else None
    out['eligible_frames'] = t.eligible
    out['frames_without_target'] = t.empty
    out['false_vertex_frames_pct'] = 100.0 * t.false_frames / t.empty if t.empty else None
    out['time_ms'] = {'median': float(np.median(times)), 'p95': float(np.percentile(times, 95)),
                      'frames': len(t.times_ms)}
    return out


def _fmt(x: float | None, spec: str = '.1f') -> str:
    return '-' if x is None else format(x, spec)


def run(args: argparse.Namespace) -> int:
    if args.threads:
        cv2.setNumThreads(args.threads)  # the budget is per core: time one thread by default
    tally = Tally()
    for path in args.bags:
        bench_bag(path, args.target, args.max_frames, tally)
    fig = figures(tally)
    if args.json:
        print(json.dumps(fig, indent=2))
        return 0
    print('Table 2 (ours | paper)        precision %      recall %       median delta/l')
    for lab in LABELS:
        setting = 'sheet of paper' if lab == 'sheet' else f'cube {lab}'
        kind = 'sheet' if lab == 'sheet' else 'cube'
        f = fig[lab]
        err = fig[kind + '_corner']['median_rel']
        print(f'  {setting:<26} {_fmt(f["precision_pct"]):>6} | {PAPER[lab][0]:<5}  '
              f'{_fmt(f["recall_pct"]):>6} | {PAPER[lab][1]:<5}  '
              f'{_fmt(err, ".4f"):>7} | {PAPER[kind + "_err"]} (mean)')
    for kind in ('cube', 'sheet'):
        c = fig[kind + '_corner']
        print(f'  {kind} corners: n {c["n"]}, median {_fmt(c["median_px"], ".2f")} px, '
              f'p95 {_fmt(c["p95_px"], ".2f")} px')
    print(f'  detection rate: {_fmt(fig["detection_rate_pct"])}% of {fig["eligible_frames"]} '
          f'frames with a target >= 0.5% of the image')
    print(f'  frames with vertices but no target: {_fmt(fig["false_vertex_frames_pct"])}% of '
          f'{fig["frames_without_target"]}')
    print(f'  time per frame: median {fig["time_ms"]["median"]:.1f} ms, '
          f'p95 {fig["time_ms"]["p95"]:.1f} ms ({fig["time_ms"]["frames"]} frames)')
    return 0
