"""
Realistic variants of the six SmartDoc 2015 frames (../smartdoc15, CC BY 4.0), to check that the
sheet detector generalises beyond them: a camera rotation and zoom (H = K R K^-1 with the
frames' estimated f = 1653 px, principal point at the centre, so the page stays an A4 seen by a
pinhole camera), desk texture (the high-pass of crops from the frames' own borders: wood,
magazine, cable, mug) outside the page, a cable or a pen across one side, an illumination
gradient and colour cast, defocus or motion blur, noise, 1280x720 and JPEG quality 35-90.

  python make_variants.py OUTDIR SEED N     (writes OUTDIR/NNN_<model>.jpg and OUTDIR/gt.json)

The frames here are five of seeds 1 and 2 (tuning); seed 777 was the held-out set.
"""
import csv
import json
import os
from pathlib import Path
import sys

import cv2
import numpy as np

SMARTDOC = Path(__file__).resolve().parents[1] / 'smartdoc15'


def load() -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    out = []
    with open(SMARTDOC / 'ground_truth.csv') as f:
        for r in csv.DictReader(f):
            im = cv2.imread(str(SMARTDOC / 'frames' / r['image_path'].replace('/', '_')))
            p = np.array([[float(r[k + '_x']), float(r[k + '_y'])]
                          for k in ('tl', 'tr', 'br', 'bl')])
            out.append((r['model_name'], r['bg_name'], im, p))
    return out


def texture(rng: np.random.Generator, imgs: list, h: int, w: int) -> np.ndarray:
    """High-pass of a crop from a frame's left or right border, stretched to (h, w)."""
    im = imgs[rng.integers(len(imgs))][2]
    x0, x1 = (0, 500) if rng.random() < 0.5 else (1420, 1920)
    crop = cv2.resize(im[:, x0:x1].astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
    return crop - cv2.GaussianBlur(crop, (0, 0), 25)


def rotate(rng: np.random.Generator, img: np.ndarray, q: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """A camera rotation of 5-35 degrees and a zoom of 0.75-1.25 keeping the page in view."""
    h, w = img.shape[:2]
    c = np.array([(w - 1) / 2, (h - 1) / 2])
    K = np.array([[1653.0, 0, c[0]], [0, 1653.0, c[1]], [0, 0, 1]])
    H = np.eye(3)
    for _ in range(50):
        ax = rng.normal(size=3)
        R = cv2.Rodrigues(ax / np.linalg.norm(ax) * np.deg2rad(rng.uniform(5, 35)))[0]
        z = rng.uniform(0.75, 1.25)
        Z = np.array([[z, 0, c[0] * (1 - z)], [0, z, c[1] * (1 - z)], [0, 0, 1]])
        H_ = Z @ K @ R @ np.linalg.inv(K)
        qq = cv2.perspectiveTransform(q.reshape(-1, 1, 2), H_).reshape(-1, 2)
        if qq.min() > 20 and (qq[:, 0] < w - 20).all() and (qq[:, 1] < h - 20).all() and \
                cv2.contourArea(qq.astype(np.float32)) > 0.04 * w * h:
            H = H_
            break
    img = cv2.warpPerspective(img, H, (w, h), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REFLECT)
    return img, cv2.perspectiveTransform(q.reshape(-1, 1, 2), H).reshape(-1, 2)


def occluder(rng: np.random.Generator, img: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, str]:
    """A cable (dark line) or a pen (coloured bar) across one side of the page."""
    h, w = img.shape[:2]
    k = int(rng.integers(4))
    a, b = q[k], q[(k + 1) % 4]
    m = a + rng.uniform(0.25, 0.75) * (b - a)
    d = rng.normal(size=2)
    d /= np.linalg.norm(d)
    half = rng.uniform(60, 200) * (w / 1920)
    p0, p1 = m - half * d, m + half * d
    if rng.random() < 0.5:
        col, th, name = (20.0, 20.0, 25.0), int(rng.integers(6, 14) * w / 1920), 'cable'
    else:
        col = tuple(float(x) for x in rng.uniform(0, 255, 3))
        th, name = int(rng.integers(20, 40) * w / 1920), 'pen'
    occl = np.zeros((h, w), np.float32)
    cv2.line(occl, tuple(np.round(p0 * 16).astype(int)), tuple(np.round(p1 * 16).astype(int)),
             1.0, th, cv2.LINE_AA, 4)
    occl = cv2.GaussianBlur(occl, (0, 0), 1.0)[..., None]
    return img * (1 - occl) + occl * np.array(col, np.float32), name


def variant(rng: np.random.Generator, imgs: list, i: int) -> tuple[str, np.ndarray, dict]:
    name, bg, im, p = imgs[i % len(imgs)]
    img, q = im.astype(np.float32), p.copy()
    h, w = img.shape[:2]
    ops = []
    if rng.random() < 0.7:
        img, q = rotate(rng, img, q)
        ops.append('persp')
    if rng.random() < 0.5 and bg != 'background05':  # (there: other pages around the page)
        mask = np.zeros((h, w), np.float32)
        cv2.fillConvexPoly(mask, np.round(q * 16).astype(np.int32), 1.0, cv2.LINE_AA, 4)
        mask = cv2.GaussianBlur(mask, (0, 0), 0.7)
        img = img + (1 - mask)[..., None] * texture(rng, imgs, h, w) * rng.uniform(0.6, 1.5)
        ops.append('texture')
    if rng.random() < 0.3:
        img, what = occluder(rng, img, q)
        ops.append(what)
    if rng.random() < 0.6:
        yy, xx = np.mgrid[:h, :w].astype(np.float32)
        ang = rng.uniform(0, 2 * np.pi)
        g = np.cos(ang) * (xx / w - 0.5) + np.sin(ang) * (yy / h - 0.5)
        img = img * (1 + rng.uniform(0.2, 0.6) * g)[..., None] * rng.uniform(0.85, 1.1, 3)
        ops.append('light')
    if rng.random() < 0.5:
        if rng.random() < 0.5:
            img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.8, 2.0))
            ops.append('defocus')
        else:
            n = int(rng.integers(5, 13))
            k = np.zeros((n, n), np.float32)
            k[n // 2] = 1.0 / n
            k = cv2.warpAffine(k, cv2.getRotationMatrix2D(((n - 1) / 2, (n - 1) / 2),
                                                          rng.uniform(0, 180), 1.0), (n, n))
            img = cv2.filter2D(img, -1, k / k.sum())
            ops.append(f'motion{n}')
    img = img + rng.normal(0, rng.uniform(1, 4), img.shape)
    if rng.random() < 0.4:
        img = cv2.resize(img, (1280, 720), interpolation=cv2.INTER_AREA)
        q = (q + 0.5) * (1280 / 1920) - 0.5
        ops.append('720p')
    qual = int(rng.integers(35, 90))
    ok, jpg = cv2.imencode('.jpg', np.clip(img, 0, 255).astype(np.uint8),
                           [cv2.IMWRITE_JPEG_QUALITY, qual])
    return f'{i:03d}_{name}.jpg', jpg, {'corners': q.tolist(), 'bg': bg,
                                        'ops': ops + [f'jpeg{qual}']}


def main() -> int:
    out, seed, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    os.makedirs(out, exist_ok=True)
    rng = np.random.default_rng(seed)
    imgs = load()
    gts = {}
    for i in range(n):
        fn, jpg, gt = variant(rng, imgs, i)
        jpg.tofile(os.path.join(out, fn))
        gts[fn] = gt
    with open(os.path.join(out, 'gt.json'), 'w') as f:
        json.dump(gts, f, indent=0)
    return 0


if __name__ == '__main__':
    sys.exit(main())
