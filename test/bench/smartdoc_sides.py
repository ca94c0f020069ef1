"""
How much edge each side of the SmartDoc pages shows, against the printed content inside them.

For every side (between the annotated corners, 3-97 % of its length, 300 samples) and each
CIELAB channel: the fraction of the samples where, within 1 px of the line, the channel's
gradient (Gaussian sigma 1.5 px) is at least ``--min-grad`` per px and within ``--max-deg`` of
the side's normal, with one polarity along the whole side. 'side' is the best such line within
``--near-px`` of the annotated side; 'inner' the best line parallel to it 20-150 px inside the
page (text columns, table rules, photographs). A side that shows less than the content inside
it cannot be told from it by any side score, whatever proposes the lines.

  python test/bench/smartdoc_sides.py [--min-grad 0.7] [--max-deg 20] [--near-px 4]
"""
import argparse
import csv
from pathlib import Path
import sys

import cv2
import numpy as np
import numpy.typing as npt

SMARTDOC = Path(__file__).resolve().parents[1] / 'data' / 'smartdoc15'
Array = npt.NDArray[np.float64]


def frames() -> list[tuple[str, npt.NDArray[np.uint8], Array]]:
    """(model name, BGR frame, (4, 2) annotated corners tl tr br bl px) of each frame."""
    out = []
    with open(SMARTDOC / 'ground_truth.csv') as f:
        for row in csv.DictReader(f):
            img = cv2.imread(str(SMARTDOC / 'frames' / row['image_path'].replace('/', '_')))
            out.append((row['model_name'], img, np.array(
                [[float(row[k + '_x']), float(row[k + '_y'])] for k in ('tl', 'tr', 'br', 'bl')])))
    return out


def coverage(gx: npt.NDArray[np.float32], gy: npt.NDArray[np.float32], a: Array, b: Array,
             inward: Array, offsets: Array, args: argparse.Namespace) -> Array:
    """(len(offsets),) edge coverage of the lines from ``a`` to ``b`` moved ``offsets`` px
    along the unit ``inward`` normal."""
    base = a + np.linspace(0.03, 0.97, 300)[:, None] * (b - a)
    shift = offsets[:, None] + np.arange(-1, 2)[None, :]  # (O, 3): each line and 1 px around
    pts = base[:, None, None, :] + shift[None, :, :, None] * inward
    xs = pts[..., 0].reshape(len(base), -1).astype(np.float32)
    ys = pts[..., 1].reshape(len(base), -1).astype(np.float32)
    gxs = cv2.remap(gx, xs, ys, cv2.INTER_LINEAR).reshape(pts.shape[:3])
    gys = cv2.remap(gy, xs, ys, cv2.INTER_LINEAR).reshape(pts.shape[:3])
    mag = np.hypot(gxs, gys)
    across = (gxs * inward[0] + gys * inward[1]) / np.maximum(mag, 1e-6)
    aligned = (mag >= args.min_grad) & (np.abs(across) >= np.cos(np.deg2rad(args.max_deg)))
    return np.maximum((aligned & (across > 0)).any(axis=2).mean(axis=0),
                      (aligned & (across < 0)).any(axis=2).mean(axis=0))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--min-grad', type=float, default=0.7, help='grey levels per px')
    ap.add_argument('--max-deg', type=float, default=20.0)
    ap.add_argument('--near-px', type=int, default=4)
    args = ap.parse_args(argv)
    print('% of each side (tl-tr, tr-br, br-bl, bl-tl) with an edge, side/inner, L a* b*')
    for name, img, corners in frames():
        lab = cv2.GaussianBlur(cv2.cvtColor(img, cv2.COLOR_BGR2LAB).astype(np.float32),
                               (0, 0), 1.5)
        gx, gy = cv2.Sobel(lab, cv2.CV_32F, 1, 0) / 8, cv2.Sobel(lab, cv2.CV_32F, 0, 1) / 8
        cells = []
        for a, b in zip(corners, np.roll(corners, -1, axis=0)):
            d = (b - a) / np.linalg.norm(b - a)
            inward = np.array([-d[1], d[0]])
            inward *= np.sign(inward @ (corners.mean(axis=0) - a))
            near = np.arange(-args.near_px, args.near_px + 1, dtype=np.float64)
            cells.append(' '.join(
                '%3.0f/%3.0f' % (100 * coverage(gx[..., c], gy[..., c], a, b, inward, near,
                                                args).max(),
                                 100 * coverage(gx[..., c], gy[..., c], a, b, inward,
                                                np.arange(20.0, 151.0, 2.0), args).max())
                for c in range(3)))
        print(f'{name:<13s} ' + ' | '.join(cells))
    return 0


if __name__ == '__main__':
    sys.exit(main())
