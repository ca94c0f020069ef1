"""
``absscale bench detect BAG...``: detection accuracy and speed against the simulator's gt.json.

Per frame: face / sheet pixel precision and recall (the paper's eq. 10-11, pixels pooled over
all frames; true pixels are those of targets covering >= 0.5% of the image, so a smaller
target that is reported counts as false positives), corner error as delta / l (Table 2: l is
the longer image edge at the vertex) and in px, detection rate over frames where a target
covers >= 0.5% of the image, frames with vertices although no target is visible, and time per
frame (decode excluded; one OpenCV thread unless --threads). Frames go through the detector
in order, as in the vertex_detector node (the cube looked for first around the last frame's:
``cube_track``; a rectangle's aspect judged over the last frames: ``sheet_track``). Prints a
table shaped like the paper's Table 2 with the paper's figures beside ours, every figure
twice: over all frames and over the frames whose longest motion-blur
streak (gt.json ``motion_blur_px``) is at most ``--max-blur`` px. ``--dump-misses DIR`` writes
each missed frame (a target covering the 0.5% area but no vertex matched) as a PNG with the
detections and the true vertices drawn.
"""
import argparse
import json
import os
import time
from typing import Any

import cv2
import numpy as np

from absscale_ros import bagio, conversions
from absscale_ros.core import cube_track, detect, sheet_track

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
    parser.add_argument('--max-blur', type=float, default=30.0,
                        help='second column: frames with motion_blur_px at most this (px)')
    parser.add_argument('--dump-misses', metavar='DIR', default='',
                        help='write missed frames with detections and true vertices as PNG')


def _mask(shape: tuple[int, int], rings: list[Any], holes: list[Any]) -> np.ndarray:
    m = np.zeros(shape, np.uint8)
    if rings:
        cv2.fillPoly(m, [np.asarray(r, np.int32).reshape(-1, 1, 2) for r in rings], 1)
    if holes:
        cv2.fillPoly(m, [np.asarray(r, np.int32).reshape(-1, 1, 2) for r in holes], 0)
    return m


def _poly_mask(shape: tuple[int, int], poly_px: np.ndarray) -> np.ndarray:
    """
    Pixels whose centre lies inside a float polygon (K, 2) px. ``cv2.fillPoly`` also fills
    every pixel its outline touches, about half a pixel all round (1 % of a sheet's pixels,
    as much as the precision target leaves), so pixels near the outline are tested exactly.
    """
    m = np.zeros(shape, np.uint8)
    pts = np.round(poly_px * 256).astype(np.int32).reshape(-1, 1, 2)
    cv2.fillPoly(m, [pts], 1, lineType=cv2.LINE_8, shift=8)
    near = np.zeros(shape, np.uint8)
    cv2.polylines(near, [pts], True, 1, thickness=3, lineType=cv2.LINE_8, shift=8)
    vs, us = np.nonzero(near & m)
    m[vs, us] = _inside(np.stack([us, vs], axis=1).astype(float), poly_px)
    return m


def _inside(points_px: np.ndarray, poly_px: np.ndarray) -> np.ndarray:
    """(N,) uint8: 1 where a point (N, 2) lies inside the polygon (K, 2) (crossing number)."""
    a, b = poly_px, np.roll(poly_px, -1, axis=0)
    x, y = points_px[:, :1], points_px[:, 1:]
    spans = (a[:, 1] > y) != (b[:, 1] > y)  # (N, K) edges crossing the point's row
    with np.errstate(divide='ignore', invalid='ignore'):
        cross_x = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return (np.count_nonzero(spans & (x < cross_x), axis=1) % 2).astype(np.uint8)


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
           shape: tuple[int, int], tally: Tally) -> bool:
    """Add one frame to ``tally``; return True when a target was eligible but missed."""
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
    return eligible and not hit


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


def bench_bag(path: str, target: str, max_frames: int, tally: Tally,
              sharp: Tally | None = None, max_blur_px: float = 30.0, dump_dir: str = '') -> None:
    """
    Add every frame of one bag to ``tally``, and frames blurred at most ``max_blur_px`` to
    ``sharp``; write missed frames to ``dump_dir`` when given.
    """
    with open(path + '.gt.json') as f:
        gt = json.load(f)
    if target == 'from-gt':
        target = gt['scene']['variant']['target']
    K = np.array(gt['camera']['K'], float)
    dist = np.array(gt['camera']['D'], float) if gt['camera'].get('D') else None
    cfg = detect.DetectConfig(target=target)
    tracker = cube_track.CubeTracker(cfg.cube)  # frames in order, as the detector node sees them
    sheets = sheet_track.SheetHistory()
    topic = gt['bag']['image_topic']
    with bagio.open_bag(path) as reader:
        for k, bm in enumerate(reader.messages([topic])):
            if max_frames and k >= max_frames:
                break
            msg = reader.deserialize(bm)
            compressed = bm.msgtype.endswith('CompressedImage')
            img = (conversions.compressed_msg_to_bgr(msg) if compressed
                   else conversions.image_msg_to_bgr(msg))
            t0 = time.process_time()  # CPU time of this process: other load does not count
            res = detect.detect(img, cfg, K, dist, tracker, sheets)
            ms = 1e3 * (time.process_time() - t0)
            fr = gt['frames'][k]
            blur = float(fr.get('motion_blur_px') or 0.0)
            for t in (tally, sharp) if sharp is not None and blur <= max_blur_px else (tally,):
                t.times_ms.append(ms)
                missed = _frame(gt, fr, res, img.shape[:2], t)
            if missed and dump_dir:
                _dump(dump_dir, path, k, blur, img, res, fr)


def _dump(dump_dir: str, path: str, k: int, blur: float, img: np.ndarray,
          res: detect.FrameDetections, fr: dict[str, Any]) -> None:
    """Write a missed frame with detections (coloured) and true vertices (white rings)."""
    out = detect.draw_overlay(img, res)
    for tf in fr['targets']:
        for v, vis in zip(tf['vertices_px'], tf['vertex_visible']):
            if v is not None and vis:
                cv2.circle(out, (int(round(v[0])), int(round(v[1]))), 9, (255, 255, 255), 2)
    cv2.putText(out, f'frame {k} blur {blur:.0f} px', (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8,
                (0, 0, 255), 2, cv2.LINE_AA)
    os.makedirs(dump_dir, exist_ok=True)
    stem = os.path.basename(path).rsplit('.', 1)[0]
    cv2.imwrite(os.path.join(dump_dir, f'{stem}_{k:04d}_blur{blur:.0f}.png'), out)


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


def _rows(fig: dict[str, Any]) -> list[tuple[str, str, str]]:
    """Return (label, our figure, paper's figure) rows of one set of figures."""
    rows = []
    for lab in LABELS:
        setting = 'sheet of paper' if lab == 'sheet' else f'cube {lab}'
        kind = 'sheet' if lab == 'sheet' else 'cube'
        f = fig[lab]
        rows += [(f'{setting} precision %', _fmt(f['precision_pct']), str(PAPER[lab][0])),
                 (f'{setting} recall %', _fmt(f['recall_pct']), str(PAPER[lab][1]))]
        if lab in ('purple', 'sheet'):
            c = fig[kind + '_corner']
            rows += [(f'{kind} median delta/l', _fmt(c['median_rel'], '.4f'),
                      f'{PAPER[kind + "_err"]} (mean)'),
                     (f'{kind} corners n', str(c['n']), ''),
                     (f'{kind} median / p95 px',
                      f'{_fmt(c["median_px"], ".2f")} / {_fmt(c["p95_px"], ".2f")}', '')]
    t = fig['time_ms']
    rows += [('detection rate %', _fmt(fig['detection_rate_pct']), ''),
             ('eligible frames (>= 0.5% area)', str(fig['eligible_frames']), ''),
             ('false-vertex frames %', _fmt(fig['false_vertex_frames_pct']), ''),
             ('frames without target', str(fig['frames_without_target']), ''),
             ('CPU ms/frame median / p95', f'{t["median"]:.1f} / {t["p95"]:.1f}', ''),
             ('frames', str(t['frames']), '')]
    return rows


def run(args: argparse.Namespace) -> int:
    if args.threads:
        cv2.setNumThreads(args.threads)  # the budget is per core: time one thread by default
    max_blur = getattr(args, 'max_blur', 30.0)
    tally, sharp = Tally(), Tally()
    for path in args.bags:
        bench_bag(path, args.target, args.max_frames, tally, sharp, max_blur,
                  getattr(args, 'dump_misses', ''))
    fig = figures(tally)
    fig_sharp = figures(sharp) if sharp.times_ms else None
    if args.json:
        fig[f'blur_le_{max_blur:g}px'] = fig_sharp
        print(json.dumps(fig, indent=2))
        return 0
    print(f'Table 2 (CPU time: process time, {args.threads or "default"} OpenCV thread(s), '
          'decode excluded)')
    print(f'  {"figure":<32} {"all frames":>14} {f"blur <= {max_blur:g} px":>15}  paper')
    sharp_rows = _rows(fig_sharp) if fig_sharp else None
    for i, (name, ours, paper) in enumerate(_rows(fig)):
        second = sharp_rows[i][1] if sharp_rows else '-'
        print(f'  {name:<32} {ours:>14} {second:>15}  {paper}')
    return 0
