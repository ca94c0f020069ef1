"""
Quadrilateral hypotheses from straight edges, scored by gradient support on all four sides.

A page lying on other pages, on a desk of almost the same white, or with a pen or a cable
across it forms no closed region in any threshold mask, but its four sides are still long
straight edges. Edge pixels (Canny on the colour image, so a step in tint counts as much as a
step in brightness) vote in a Hough accumulator only near their own gradient direction, which
keeps weak, broken edges of a long side together and text strokes apart. Each Hough peak is
a line; along it, a support profile marks the points where an edge pixel lies within a pixel
and its gradient is perpendicular to the line. With cumulative sums of these profiles, the
support of any side between two corners costs O(1), so every cycle of four lines (two roughly
opposite pairs meeting at corners) is scored, and kept when every side is supported from
corner to corner. Only the object's own outline is: a quadrilateral that borrows a side from
a page underneath has a gap near a corner, one built from a printed table on the page is
dropped by the caller's aspect check or outscored by the page around it.
"""
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class QuadConfig:
    """
    Thresholds of the line-based hypotheses (work-image px unless stated).

    :param min_side_px: the shortest side a hypothesis may have.
    :param canny_low: lower Canny threshold (colour image, 0-255 scale).
    :param canny_high: upper Canny threshold.
    :param theta_res_deg: Hough angle bin.
    :param vote_span_deg: an edge pixel votes within this angle of its gradient direction.
    :param peak_frac: smallest Hough peak, fraction of ``min_side_px``.
    :param max_lines: strongest Hough peaks kept; bounds the number of hypotheses.
    :param min_corner_deg: smallest angle between two sides meeting at a corner.
    :param max_opposite_deg: largest angle between two opposite sides (perspective).
    :param grad_cos: smallest cosine between an edge pixel's gradient and the side normal.
    :param min_support: smallest gradient support of every side, corner to corner.
    :param max_quads: hypotheses returned, best first.
    :param max_cycles: four-line cycles scored at most (bounds the time in cluttered scenes).
    :param segment_lines: lines of straight segments (OpenCV's LSD on grey) added to the Hough
        peaks, at most this many, longest first (0: none). The Hough votes of a short side
        next to a stronger line (desk texture a few degrees off) merge into that line's peak.
    :param segment_frac: shortest segment used, fraction of ``min_side_px``.
    """

    min_side_px: float = 20.0
    canny_low: int = 8
    canny_high: int = 20
    theta_res_deg: float = 0.5
    vote_span_deg: float = 6.0
    peak_frac: float = 0.5
    max_lines: int = 40
    min_corner_deg: float = 30.0
    max_opposite_deg: float = 45.0
    grad_cos: float = 0.9
    min_support: float = 0.7
    max_quads: int = 64
    max_cycles: int = 4000
    segment_lines: int = 0
    segment_frac: float = 0.5


class EdgeMap:
    """
    Colour edges of a work image: Canny pixels and the unit gradient of their strongest channel.

    :param work_bgr: (H, W, 3) uint8 work image.
    :ivar pix: (N, 2) float64 edge pixel positions (u, v).
    :ivar normal: (N, 2) float64 unit gradient directions at those pixels.
    """

    def __init__(self, work_bgr: npt.NDArray[np.uint8], cfg: QuadConfig) -> None:
        blurred = cv2.GaussianBlur(work_bgr, (0, 0), 1.0)
        v, u = np.nonzero(cv2.Canny(blurred, cfg.canny_low, cfg.canny_high))
        gx = cv2.Sobel(blurred, cv2.CV_16S, 1, 0)[v, u].astype(np.float64)
        gy = cv2.Sobel(blurred, cv2.CV_16S, 0, 1)[v, u].astype(np.float64)
        best = np.argmax(gx * gx + gy * gy, axis=1)[:, None]
        g = np.stack([np.take_along_axis(gx, best, 1)[:, 0],
                      np.take_along_axis(gy, best, 1)[:, 0]], axis=1)
        self.pix = np.stack([u, v], axis=1).astype(np.float64)
        self.normal = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-9)
        self.shape = work_bgr.shape[:2]


def hough_lines(em: EdgeMap, cfg: QuadConfig) -> Array:
    """
    Return (M, 3) lines ``a b c`` (unit normal) at the strongest orientation-aware Hough peaks.

    Each edge pixel votes for the lines through it whose normal is within ``vote_span_deg`` of
    its gradient, so collinear fragments add up and crossing texture does not.
    """
    if len(em.pix) == 0:
        return np.zeros((0, 3))
    n_theta = int(round(180.0 / cfg.theta_res_deg))
    span = int(round(cfg.vote_span_deg / cfg.theta_res_deg))
    # Rows for theta in [-span, n_theta + span] bins: no wrap-around, so a line near theta = 0
    # collects all its votes in one peak (its twin at theta + 180 deg is merged below).
    angles = np.arange(-span, n_theta + span + 1) * (np.pi / n_theta)
    cos_t, sin_t = np.cos(angles), np.sin(angles)
    theta_pix = np.mod(np.arctan2(em.normal[:, 1], em.normal[:, 0]), np.pi)
    rows = np.rint(theta_pix / np.pi * n_theta).astype(np.int64)[:, None] + \
        np.arange(0, 2 * span + 1)[None, :]
    rho_max = int(np.ceil(np.hypot(*em.shape))) + 1
    width = 2 * rho_max + 1
    rho = np.rint(em.pix[:, :1] * cos_t[rows] + em.pix[:, 1:] * sin_t[rows]).astype(np.int64)
    acc = np.bincount((rows * width + rho + rho_max).ravel(),
                      minlength=len(angles) * width).reshape(len(angles), width)
    acc = cv2.GaussianBlur(acc.astype(np.float32), (3, 3), 0)
    peaks = (acc >= cv2.dilate(acc, np.ones((2 * span + 1, 5), np.uint8))) & \
        (acc >= cfg.peak_frac * cfg.min_side_px)
    kk, rr = np.nonzero(peaks)
    order = np.argsort(-acc[kk, rr])[:3 * cfg.max_lines]
    kk, rr = kk[order], rr[order]
    ls = np.stack([cos_t[kk], sin_t[kk], -(rr - rho_max).astype(np.float64)], axis=1)
    return _unique(ls)[:cfg.max_lines]


def segment_lines(work_bgr: npt.NDArray[np.uint8], cfg: QuadConfig) -> Array:
    """
    Return (M, 3) lines ``a b c`` (unit normal) through the longest straight segments of the
    grey image (LSD), one per line: a segment collinear with a longer one (within 2 degrees
    and 1.5 px at its middle) is part of it.
    """
    if cfg.segment_lines <= 0:
        return np.zeros((0, 3))
    found = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD).detect(
        cv2.cvtColor(work_bgr, cv2.COLOR_BGR2GRAY))[0]
    if found is None:
        return np.zeros((0, 3))
    seg = found.reshape(-1, 4).astype(np.float64)
    d = seg[:, 2:] - seg[:, :2]
    length = np.hypot(d[:, 0], d[:, 1])
    keep = np.argsort(-length)
    keep = keep[length[keep] >= cfg.segment_frac * cfg.min_side_px]
    seg, d, length = seg[keep], d[keep], length[keep]
    normal = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.maximum(length, 1e-9)[:, None]
    mid = 0.5 * (seg[:, :2] + seg[:, 2:])
    ls = np.concatenate([normal, -(normal * mid).sum(axis=1, keepdims=True)], axis=1)
    out: list[int] = []
    for i in range(len(ls)):
        dots = ls[out, :2] @ ls[i, :2]
        off = np.abs(ls[out, :2] @ mid[i] + ls[out, 2])
        if not ((np.abs(dots) > np.cos(np.deg2rad(2.0))) & (off < 1.5)).any():
            out.append(i)
            if len(out) == cfg.segment_lines:
                break
    return ls[out]


def _unique(ls: Array) -> Array:
    """Drop lines that repeat an earlier one (the same line seen at theta and theta + 180)."""
    keep: list[int] = []
    for i, line in enumerate(ls):
        dots = ls[keep, :2] @ line[:2]
        same = (np.abs(dots) > 0.9998) & (np.abs(ls[keep, 2] * np.sign(dots) - line[2]) < 2.0)
        if not same.any():
            keep.append(i)
    return ls[keep]


def support_profiles(em: EdgeMap, ls: Array, cfg: QuadConfig) -> tuple[Array, Array]:
    """
    Return cumulative support along each line at 1 px steps.

    A step is supported when an edge pixel within 1 px of the line projects into it and its
    gradient is within ``acos(grad_cos)`` of the line normal (either polarity).

    :returns: ((M, L + 1) cumulative count of supported steps, (L,) step positions ``t``
        along the direction ``(-b, a)`` from the foot of the line's normal).
    """
    half = int(np.ceil(np.hypot(*em.shape)))
    ts = np.arange(-half, half + 1, dtype=np.float64)
    d = np.stack([-ls[:, 1], ls[:, 0]], axis=1)
    near = ((np.abs(ls[:, :2] @ em.pix.T + ls[:, 2:3]) <= 1.0)
            & (np.abs(ls[:, :2] @ em.normal.T) >= cfg.grad_cos))
    row, col = np.nonzero(near)
    pos = np.rint(np.einsum('ij,ij->i', d[row], em.pix[col])).astype(np.intp) + half
    ok = np.zeros((len(ls), len(ts)), dtype=bool)
    ok[row, pos] = True
    cum = np.zeros((len(ls), len(ts) + 1))
    cum[:, 1:] = np.cumsum(ok, axis=1)
    return cum, ts


def _side_table(ls: Array, cum: Array, ts: Array, cfg: QuadConfig
                ) -> tuple[Array, npt.NDArray[np.bool_], Array]:
    """
    Return (M, M, 2) pairwise intersections, (M, M, M) valid sides and their support.

    ``valid[i, j, k]``: line ``j`` from its corner with ``i`` to its corner with ``k`` is a
    side: both corners sharp enough, ``i`` and ``k`` roughly opposite, long enough, and
    supported at least ``min_support`` of its length.
    """
    m = len(ls)
    cross = np.cross(ls[:, None, :], ls[None, :, :])
    den = np.where(np.abs(cross[..., 2]) < 1e-9, 1e-9, cross[..., 2])
    pts = cross[..., :2] / den[..., None]
    cosang = np.abs(ls[:, :2] @ ls[:, :2].T)
    corner = cosang < np.cos(np.deg2rad(cfg.min_corner_deg))
    opposite = (cosang > np.cos(np.deg2rad(cfg.max_opposite_deg))) & ~np.eye(m, dtype=bool)
    d = np.stack([-ls[:, 1], ls[:, 0]], axis=1)
    pos = np.einsum('jk,jik->ji', d, pts)  # pos[j, i]: corner with i along line j
    idx = np.clip(np.rint(pos - ts[0]).astype(np.intp), 0, len(ts))
    rows = np.arange(m)[None, :, None]
    a, b = idx.T[:, :, None], idx[None, :, :]  # corner with i, corner with k, on line j
    length = np.abs(pos.T[:, :, None] - pos[None, :, :])
    support = np.abs(cum[rows, b] - cum[rows, a]) / np.maximum(length, 1.0)
    valid = (corner.T[:, :, None] & corner[None, :, :] & opposite[:, None, :]
             & (length >= cfg.min_side_px) & (support >= cfg.min_support))
    return pts, valid, support


def find_quads(work_bgr: npt.NDArray[np.uint8], cfg: QuadConfig) -> tuple[Array, Array]:
    """
    Return the best-supported quadrilaterals of a work image.

    :param work_bgr: (H, W, 3) uint8 work image.
    :returns: ((Q, 4, 2) corners px, (Q, 4) per-side support), best first.
    """
    em = EdgeMap(work_bgr, cfg)
    ls = hough_lines(em, cfg)
    if cfg.segment_lines > 0:
        ls = _unique(np.concatenate([ls, segment_lines(work_bgr, cfg)]))
    if len(ls) < 4:
        return np.zeros((0, 4, 2)), np.zeros((0, 4))
    cum, ts = support_profiles(em, ls, cfg)
    pts, valid, support = _side_table(ls, cum, ts, cfg)
    blocks = []
    for i, k in zip(*np.nonzero(np.triu(valid.any(axis=1), 1))):
        js = np.flatnonzero(valid[i, :, k])
        ls_ = np.flatnonzero(valid[k, :, i])
        js, ls_ = js[js > i], ls_[ls_ > i]  # i is the cycle's smallest line index
        if not len(js) or not len(ls_):
            continue
        closed = valid[js][:, k][:, ls_] & valid[ls_][:, i][:, js].T
        a, b = np.nonzero(closed & (js[:, None] < ls_[None, :]))  # one direction per cycle
        if len(a):
            blocks.append(np.stack([np.full(len(a), i), js[a], np.full(len(a), k), ls_[b]], 1))
        if sum(len(x) for x in blocks) >= cfg.max_cycles:
            break
    if not blocks:
        return np.zeros((0, 4, 2)), np.zeros((0, 4))
    c = np.concatenate(blocks)[:cfg.max_cycles]
    nxt, prv = np.roll(c, -1, axis=1), np.roll(c, 1, axis=1)
    quads = pts[c, nxt]  # corner of side c[:, m] with the next side
    quads = np.roll(quads, 1, axis=1)  # corners in order: (l, i), (i, j), (j, k), (k, l)
    sups = support[prv, c, nxt]
    q, s = quads, sups
    convex = convex_area(q) > 0
    q, s = q[convex], s[convex]
    order = np.argsort(-s.mean(axis=1))[:cfg.max_quads]
    return q[order], s[order]


def convex_area(quads: Array) -> Array:
    """Return the (Q,) area of convex quadrilaterals (Q, 4, 2), 0 for others."""
    e = np.roll(quads, -1, axis=1) - quads
    en = np.roll(e, -1, axis=1)
    turn = e[..., 0] * en[..., 1] - e[..., 1] * en[..., 0]
    convex = (turn > 0).all(axis=1) | (turn < 0).all(axis=1)
    return np.where(convex, _shoelace(quads), 0.0)


def _shoelace(quads: Array) -> Array:
    x, y = quads[..., 0], quads[..., 1]
    return 0.5 * np.abs((x * np.roll(y, -1, 1) - np.roll(x, -1, 1) * y).sum(axis=1))
