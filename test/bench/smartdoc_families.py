"""
Which lines of a SmartDoc page's side family show a colour step: the side against the printed
content inside the page and the other pages and desk beyond it.

A side's family is the lines through its vanishing point (where the annotated side meets the
opposite one), each at ``t`` px from the side along the adjacent sides (negative: outside the
page), sampled between the adjacent sides' lines (3-97 %). For each line and CIELAB channel the
step is the median over 200 samples of the mean 2-8 px inside minus 2-8 px outside (Gaussian
sigma 1.5 px); 'side' is the largest |step| within ``--near-px`` of the annotated side, 'in'
the largest 20-150 px inside (text, rules, photographs), 'out' the largest 20-150 px outside
(pages beneath, desk, objects). A proposer that knew the vanishing points would see the side
where it beats both. Also: where within ``--near-px`` of each annotated side the strongest
step lies (b* counted twice), and how far the corners of those four lines lie from the annotated
corners (delta / l): the error a detector of the visible outline would be charged.

  python test/bench/smartdoc_families.py [--near-px 8]
"""
import argparse
from pathlib import Path
import sys

import cv2
import numpy as np
import numpy.typing as npt

sys.path.insert(0, str(Path(__file__).resolve().parent))
from smartdoc_sides import frames  # noqa: E402

Array = npt.NDArray[np.float64]


def _homog(a: Array, b: Array) -> Array:
    return np.cross([a[0], a[1], 1.0], [b[0], b[1], 1.0])


def family_line(corners: Array, side: int, t: float) -> tuple[Array, Array]:
    """The ends (2,) px of the line of side ``side``'s family at ``t`` px (module docstring)
    on the two adjacent sides' lines."""
    a, b, c, d = (corners[(side + k) % 4] for k in range(4))
    vp = np.cross(_homog(a, b), _homog(d, c))  # (a point at infinity when parallel)
    p0 = a + t * (d - a) / np.linalg.norm(d - a)
    hit = np.cross(np.cross([p0[0], p0[1], 1.0], vp), _homog(b, c))
    return p0, hit[:2] / hit[2]


def family_steps(chans: npt.NDArray[np.float32], corners: Array, side: int, ts: Array
                 ) -> Array:
    """(len(ts), C) median step (inside minus outside) of each channel along the lines of
    side ``side``'s family (module docstring) at offsets ``ts`` px."""
    centre = corners.mean(axis=0)
    out = np.zeros((len(ts), chans.shape[2]))
    for i, t in enumerate(ts):
        p0, p1 = family_line(corners, side, t)
        u = (p1 - p0) / np.linalg.norm(p1 - p0)
        inward = np.array([-u[1], u[0]]) * np.sign(np.array([-u[1], u[0]]) @ (centre - p0))
        base = p0 + np.linspace(0.03, 0.97, 200)[:, None] * (p1 - p0)
        offs = np.concatenate([-np.arange(2.0, 9.0), np.arange(2.0, 9.0)])
        pts = (base[:, None, :] + offs[None, :, None] * inward).astype(np.float32)
        for k in range(chans.shape[2]):
            v = cv2.remap(chans[..., k], pts[..., 0], pts[..., 1], cv2.INTER_LINEAR)
            out[i, k] = np.median(v[:, 7:].mean(axis=1) - v[:, :7].mean(axis=1))
    return out


def visible_outline(chans: npt.NDArray[np.float32], corners: Array, near_px: float
                    ) -> tuple[Array, Array]:
    """(4,) offset px of the strongest step (b* counted twice) within ``near_px`` of each
    annotated side, along its family, and the (4, 2) corners where those lines meet."""
    ts = np.arange(-near_px, near_px + 0.25, 0.5)
    weighted = [(np.abs(family_steps(chans, corners, side, ts)) * (1.0, 2.0)).max(axis=1)
                for side in range(4)]
    offsets = np.array([ts[int(np.argmax(w))] for w in weighted])
    ls = [_homog(*family_line(corners, side, t)) for side, t in enumerate(offsets)]
    meet = [np.cross(ls[k - 1], ls[k]) for k in range(4)]
    return offsets, np.array([m[:2] / m[2] for m in meet])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--near-px', type=float, default=8.0)
    args = ap.parse_args(argv)
    ts = np.arange(-150.0, 151.0, 1.0)
    near = np.abs(ts) <= args.near_px
    inner, outer = (ts >= 20) & (ts <= 150), (ts <= -20) & (ts >= -150)
    print('|median step| per side (tl-tr, tr-br, br-bl, bl-tl) side/in/out, L and b*')
    for name, img, corners in frames():
        lab = cv2.GaussianBlur(cv2.cvtColor(img, cv2.COLOR_BGR2LAB).astype(np.float32),
                               (0, 0), 1.5)[..., [0, 2]]
        cells = []
        for side in range(4):
            steps = np.abs(family_steps(lab, corners, side, ts))
            cells.append(' '.join('%4.1f/%4.1f/%4.1f' % (steps[near, k].max(),
                                                         steps[inner, k].max(),
                                                         steps[outer, k].max())
                                  for k in range(2)))
        print(f'{name:<13s} ' + ' | '.join(cells))
        offsets, seen = visible_outline(lab, corners, args.near_px)
        sides = np.hypot(*(corners - np.roll(corners, -1, axis=0)).T)
        rel = np.hypot(*(seen - corners).T) / np.maximum(sides, np.roll(sides, 1))
        print(f'{"":<13s} strongest step at ' + ' '.join('%+5.1f' % t for t in offsets) +
              ' px; those lines\' corners off the annotated by %.2f %% median, %.2f %% max'
              % (100 * np.median(rel), 100 * rel.max()))
    return 0


if __name__ == '__main__':
    sys.exit(main())
