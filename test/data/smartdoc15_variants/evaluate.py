"""
The real-frame figure on a variant set (``make_variants.py OUT SEED N``): pages found (median
corner error under 2 % of the edge), wrong (a detection further off), missed, and the median
corner error of those found as the paper's delta / l, per background; as ``absscale detect
IMAGE --target a4`` runs.

  python evaluate.py OUT [-v]
"""
import json
import os
import sys
import time

import cv2
import numpy as np

from absscale_ros.core import detect, detect_sheet


def main() -> int:
    d = sys.argv[1]
    with open(os.path.join(d, 'gt.json')) as f:
        gts = json.load(f)
    cv2.setNumThreads(1)
    cfg = detect.DetectConfig(target='a4', sheet=detect_sheet.SheetConfig(line_candidates=True))
    rels, times, per_bg = [], [], {}
    for name, gt in sorted(gts.items()):
        true_px = np.array(gt['corners'])
        t0 = time.process_time()
        dets = detect.detect(cv2.imread(os.path.join(d, name)), cfg).detections
        times.append(time.process_time() - t0)
        sides = np.hypot(*(true_px - np.roll(true_px, -1, 0)).T)
        edge = np.maximum(sides, np.roll(sides, 1))
        best = None
        for det in dets:
            err = min((np.hypot(*(np.roll(det.vertices_px, k, 0) - true_px).T)
                       for k in range(4)), key=lambda e: e.sum()) / edge
            best = err if best is None or err.mean() < best.mean() else best
        # The committed set's gt.json names the variant's operations, not its background.
        counts = per_bg.setdefault(gt.get('bg', 'committed'), [0, 0, 0])
        counts[0] += 1
        status = 'miss'
        if best is not None and np.median(best) < 0.02:
            counts[1] += 1
            rels += list(best)
            status = f'ok {100 * np.median(best):.2f} %'
        elif best is not None:
            counts[2] += 1
            status = f'WRONG {100 * np.median(best):.1f} %'
        if '-v' in sys.argv:
            print(name, status, gt['ops'])
    for bg, (n, ok, wrong) in sorted(per_bg.items()):
        print(f'{bg}: {ok}/{n} found, {wrong} wrong')
    med = 100 * np.median(rels) if rels else float('nan')
    print(f'all: {sum(c[1] for c in per_bg.values())}/{len(gts)} found, '
          f'{sum(c[2] for c in per_bg.values())} wrong, median delta/l {med:.2f} %, '
          f'CPU median {1e3 * np.median(times):.0f} ms')
    return 0


if __name__ == '__main__':
    sys.exit(main())
