"""
Cube faces seen almost edge-on: thin strips of another cube colour along a detected face.

A face seen nearly edge-on is a few pixels wide: the mask opening removes it, or it fails the
roundness test, so the cube shows a single face and is not reported (a single face names no
vertex uniquely). Along each side of a detected face that no other detected face shares,
colour profiles outward from the side look for a strip of one of the other cube colours that
starts at the side and ends within ``max_width``. Its width, fitted linearly along the side (a
foreshortened face is a trapezoid), gives the strip's two far corners. The strip becomes a
thin ``Face`` sharing the side's two corners, so the cube is assembled as usual; its far
corners are measured on a few pixels only (along the side's normal, not along the unknown
third cube edge), so the detector reports the strip's outline and colour but not those
corners as vertices.
"""
import functools
from typing import Callable

import cv2
import numpy as np
import numpy.typing as npt

from absscale_ros.core import lines

Array = npt.NDArray[np.float64]
# (..., 3) uint8 BGR samples -> {colour name: (...) bool, the samples of that cube colour}
MaskFn = Callable[[npt.NDArray[np.uint8]], dict[str, npt.NDArray[np.bool_]]]
STEP_PX = 0.5  # sample spacing across the side
PROFILES = 16  # profiles per side


def _shared(face_corners: list[Array], tol_frac: float, min_tol: float
            ) -> npt.NDArray[np.int64]:
    """
    Return (F, 4) the index of another face with corners at both ends of side ``i`` of face
    ``f`` (within ``max(min_tol, tol_frac * side length)``), -1 for none, for all sides at
    once.
    """
    pts = np.concatenate(face_corners)  # (4F, 2)
    nf = len(face_corners)
    d = np.hypot(pts[:, None, 0] - pts[None, :, 0], pts[:, None, 1] - pts[None, :, 1])
    near = d.reshape(4 * nf, nf, 4).min(axis=2)  # corner -> nearest corner of each face
    ends = np.arange(4 * nf).reshape(nf, 4)
    nxt = ends[:, [1, 2, 3, 0]]
    length = np.hypot(*(pts[nxt.ravel()] - pts[ends.ravel()]).T).reshape(nf, 4)
    tol = np.maximum(min_tol, tol_frac * length)[..., None]
    both = (near[ends] < tol) & (near[nxt] < tol)  # (F, 4, F)
    both[np.arange(nf), :, np.arange(nf)] = False  # not the face itself
    return np.where(both.any(axis=2), np.argmax(both, axis=2), -1)


def _widths(inside: npt.NDArray[np.bool_], offs: Array, ks: npt.NDArray[np.int64]) -> Array:
    """
    Return (..., P) strip width px per profile (NaN when the strip does not start at the side
    or does not end inside the band): the last in-colour offset of the run from the side.

    :param inside: (..., P, K) in-colour samples along the profiles; ``ks`` (...) how many of
        the K samples each side's profiles reach (the band, within half the side).
    """
    first = np.argmax(inside[..., :4], axis=-1)  # the run may start after a mixed edge pixel
    started = inside[..., :4].any(axis=-1)
    idx = np.arange(inside.shape[-1])
    after = ~inside & (idx > first[..., None]) & (idx < ks[..., None, None])
    ends = np.where(after.any(axis=-1), np.argmax(after, axis=-1), -1)
    return np.where(started & (ends > 0), offs[np.maximum(ends - 1, 0)] + 0.5 * STEP_PX, np.nan)


def _half_step(bgr: Array, w: Array, offs: Array) -> Array:
    """
    Return (P,) strip widths moved to where the colour is half way from the strip's to the
    outside's (the colour test passes mixed edge pixels, so its widths run ~1 px long).

    :param bgr: (P, K, 3) samples along the profiles; ``w`` (P,) widths from the colour test.
    """
    wf = np.where(np.isfinite(w), w, -10.0)[:, None]
    inner = (offs > 0.5) & (offs < wf - 1.5)  # (P, K)
    outer = (offs > wf + 1.5) & (offs < wf + 3.5)
    ok = np.isfinite(w) & inner.any(axis=1) & outer.any(axis=1)
    if not ok.any():
        return w
    p = np.flatnonzero(ok)
    samples = bgr[p]
    inn, out_ = inner[p, :, None], outer[p, :, None]  # means: a few samples, all one colour
    strip = (samples * inn).sum(axis=1) / inn.sum(axis=1)  # (P', 3)
    beyond = (samples * out_).sum(axis=1) / out_.sum(axis=1)
    d = strip - beyond
    t = np.einsum('pkc,pc->pk', samples - beyond[:, None], d) / np.maximum(
        (d * d).sum(axis=1), 1e-9)[:, None]  # 1 on the strip, 0 beyond
    below = ((offs > wf[p] - 2.0) & (offs < wf[p] + 2.0)) & (t < 0.5)
    k = np.argmax(below, axis=1)  # first sample past half way, and the one before it
    crossed = below.any(axis=1) & (k > 0)
    p, k, t = p[crossed], k[crossed], t[crossed]
    t0, t1 = t[np.arange(len(k)), k - 1], t[np.arange(len(k)), k]
    out = w.copy()
    out[p] = offs[k - 1] + (t0 - 0.5) / np.maximum(t0 - t1, 1e-9) * STEP_PX
    return out


def strip_faces(image_bgr: npt.NDArray[np.uint8], corners: list[Array], colours: list[str],
                masks_of: MaskFn, max_width: float, min_width: float = 1.5,
                min_frac: float = 0.5, width_tol: float = 1.5
                ) -> list[tuple[str, Array, float, bool]]:
    """
    Return (colour, (4, 2) corners px, support, mute) of thin strips along unshared face
    sides; "mute" (no evidence for a cube pose) when the strip's colour goes on past an end
    of the side (``_runs_on``) or the strip tapers to nothing at one end.

    Strip corners are ``[c_i, far_i, far_i1, c_i1]`` for side ``c_i -> c_i1`` of its face.

    :param corners: per detected face its (4, 2) corners px (full-resolution image).
    :param colours: per face its colour name.
    :param masks_of: ``(bgr (..., 3) uint8) -> {colour: (...) bool}`` cube colour test.
    :param max_width: widest strip looked for, px (wider faces are found as faces).
    :param min_frac: share of the profiles that must find the strip: a box of the strip's
        colour just behind the cube runs some profiles on past ``max_width`` (the shape check
        then decides whether the strip agrees with the cube).
    :param width_tol: a profile this close to the strip's width line, px, agrees with it
        (``_width_line``; 0: one line through all of them).
    """
    # Every unshared side of every face, sampled in one remap and one colour test.
    ts = 0.15 + 0.7 * (np.arange(PROFILES) + 0.5) / PROFILES
    offs = np.arange(0.5, max_width + 1e-9, STEP_PX)
    cand = []  # (face, side, c0, c1, outward normal, offsets within half the side)
    shared = _shared(corners, 0.1, 3.0)
    pts = np.stack(corners)  # (F, 4, 2)
    length = np.hypot(*(pts[:, [1, 2, 3, 0]] - pts).transpose(2, 0, 1))  # (F, 4)
    reach = np.searchsorted(offs, np.minimum(max_width, 0.5 * length) + 1e-9)
    centres = pts.mean(axis=1)
    for f, i in zip(*np.nonzero((length >= 8.0) & (shared < 0))):
        c0, c1 = pts[f, i], pts[f, (i + 1) % 4]
        cand.append((int(f), int(i), c0, c1,
                     lines.line_through(c0, c1, centres[f])[:2], int(reach[f, i])))
    if not cand:
        return []
    c0s, c1s, ns = (np.array([c[j] for c in cand]) for j in (2, 3, 4))
    xy = ((c0s[:, None, :] + ts[None, :, None] * (c1s - c0s)[:, None, :])[:, :, None, :]
          + offs[None, None, :, None] * ns[:, None, None, :]).reshape(-1, len(offs), 2)
    flat = cv2.remap(image_bgr, xy[..., 0].astype(np.float32), xy[..., 1].astype(np.float32),
                     cv2.INTER_LINEAR)
    samples = flat.reshape(len(cand), PROFILES, len(offs), 3)
    masks = masks_of(flat)
    names = list(masks)
    ks = np.array([k for *_, k in cand])
    # Widths, the profiles that find a strip and their share: every colour and side at once.
    widths = _widths(np.stack([masks[c].reshape(len(cand), PROFILES, len(offs))
                               for c in names]), offs, ks)  # (C, S, P)
    oks = np.isfinite(widths) & (widths >= min_width)
    shares = oks.mean(axis=2)
    found: dict[int, list[tuple[int, str, Array, float, bool]]] = {}
    for s_, o in zip(*np.nonzero(shares.T >= min_frac)):  # (side, colour) pairs, in order
        f, i, c0, c1, n, k = cand[s_]
        other = names[o]
        if other == colours[f] or _unlike_cube(other, [colours[g] if g >= 0 else '' for g in
                                                       shared[f, [(i + 1) % 4, (i + 2) % 4,
                                                                  (i + 3) % 4]]]):
            continue
        ok = oks[o, s_]
        w = _half_step(samples[s_, :, :k].astype(np.float64), widths[o, s_], offs[:k])
        w0, w1 = _width_line(ts[ok], w[ok], width_tol)
        if max(w0, w1) < min_width or min(w0, w1) < -min_width:
            continue
        # A strip may taper to nothing (a top seen at a grazing angle: half of it above
        # each side face); so may a sliver of a box behind, so a tapered one is mute.
        tapered = min(w0, w1) < 0.5 * min_width
        w0, w1 = max(w0, 0.0), max(w1, 0.0)
        strip = np.array([c0, c0 + w0 * n, c1 + w1 * n, c1])
        found.setdefault(f, []).append((i, other, strip, float(shares[o, s_]), tapered))
    strips = [(f, j, x[2], x[1]) for f, xs in found.items() for j, x in enumerate(xs)]
    for (f, j, _, _), on in zip(strips, _runs_on(image_bgr, [x[2] for x in strips],
                                                 [x[3] for x in strips], masks_of)):
        found[f][j] = found[f][j][:4] + (on or found[f][j][4],)
    out = []
    for face_found in found.values():
        # Faces next to one face differ in colour: one colour on two neighbouring sides is a
        # box behind, not the cube.
        behind = {c for i, c, *_ in face_found for j, d, *_ in face_found
                  if c == d and (j - i) % 4 in (1, 3)}
        out += [(c, strip, sup, on) for _, c, strip, sup, on in face_found if c not in behind]
    return out


def _width_line(t: Array, w: Array, tol: float) -> tuple[float, float]:
    """
    Return a strip's widths (w0, w1) at the two ends of its side, px: a least-squares line
    (width linear along the side: a foreshortened face is a trapezoid) through the profiles'
    widths ``w`` at ``t`` (0-1 along the side) that the most of them lie within ``tol`` px
    of (0: through all of them), when that is at least half of them and every other one lies
    beyond it: where a box of the strip's colour stands behind part of it, its profiles run
    on into the box and tilt a line fitted to all of them (a box only lengthens them; a top
    whose far corner lies above the side widens, then narrows: no line fits it, and all of
    them count).
    """
    def fit(keep: npt.NDArray[np.bool_]) -> tuple[float, float]:
        tk, wk = t[keep], w[keep]
        tm, wm = tk.mean(), wk.mean()
        slope = ((tk - tm) * (wk - wm)).sum() / max(((tk - tm) ** 2).sum(), 1e-12)
        return wm - slope * tm, wm + slope * (1.0 - tm)
    i, j = _pairs(len(t))
    pair = t[j] != t[i]
    i, j = i[pair], j[pair]
    slopes = (w[j] - w[i]) / (t[j] - t[i])
    near = np.abs(w[i][:, None] + slopes[:, None] * (t[None] - t[i][:, None]) - w[None]) \
        <= tol  # (pairs, profiles): within the line through each pair of profiles
    counts = near.sum(axis=1)
    if tol <= 0.0 or not len(counts) or counts.max() == len(t) or 2 * counts.max() < len(t):
        return fit(np.ones(len(t), bool))
    best = int(np.argmax(counts))
    beyond = w > w[i[best]] + slopes[best] * (t - t[i[best]])
    return fit(near[best] if (beyond | near[best]).all() else np.ones(len(t), bool))


@functools.lru_cache(maxsize=None)
def _pairs(n: int) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """``np.triu_indices(n, 1)``, kept per ``n`` (at most ``PROFILES``; ~50 us a call)."""
    return np.triu_indices(n, 1)


def _unlike_cube(colour: str, beyond: list[str]) -> bool:
    """
    Return True when a strip of ``colour`` along a face's side cannot be a cube face: the
    colours of the faces sharing the face's next, opposite and previous sides (``''`` for
    none) show that opposite faces are alike, so the side across from a shared one borders
    that face's colour and its two neighbours the third colour (a box of a cube colour
    behind a side face, beside its far side, is no top).
    """
    nxt, opposite, prev = beyond
    return (opposite != '' and opposite != colour) or colour in (nxt, prev)


def _runs_on(image_bgr: npt.NDArray[np.uint8], strips: list[Array], colours: list[str],
             masks_of: MaskFn, min_frac: float = 0.6) -> list[bool]:
    """
    Return per strip True when its colour goes on past either end of its side (mid-width): a
    box of that colour behind the face, or the same face running on along a neighbouring
    face, so the strip's own outline says nothing about a cube face ending there. All strips
    are sampled in one remap and one colour test.
    """
    if not strips:
        return []
    xys = []
    for c0, far0, far1, c1 in strips:
        length = max(float(np.hypot(*(c1 - c0))), 1e-9)
        u = (c1 - c0) / length
        d = 3.0 + np.linspace(0.0, max(6.0, 0.2 * length), 8)
        mid0, mid1 = 0.5 * (c0 + far0), 0.5 * (c1 + far1)
        xys.append(np.stack([mid0 - d[:, None] * u, mid1 + d[:, None] * u]))
    xy = np.concatenate(xys).astype(np.float32)  # (2 per strip, 8, 2)
    bgr = cv2.remap(image_bgr, xy[..., 0], xy[..., 1], cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    masks = masks_of(bgr)
    return [bool(masks[c][2 * j:2 * j + 2].mean(axis=1).max() >= min_frac)
            for j, c in enumerate(colours)]


def best_outline(image_bgr: npt.NDArray[np.uint8], colour: str, outlines: list[Array],
                 masks_of: MaskFn) -> int:
    """
    Return the index of the outline (K, 2) px of a face of ``colour`` that the image fits
    best: the pixels inside it of that colour less those of any other (``cube_split``'s quad
    fit), in one window around all of them and one colour test.
    """
    h, w = image_bgr.shape[:2]
    pts = np.concatenate(outlines)
    x0, y0 = np.clip(np.floor(pts.min(axis=0)).astype(int) - 1, 0, [w - 1, h - 1])
    x1, y1 = np.clip(np.ceil(pts.max(axis=0)).astype(int) + 2, [x0 + 1, y0 + 1], [w, h])
    mine = masks_of(image_bgr[y0:y1, x0:x1])[colour]
    fits = []
    for outline in outlines:
        inside = np.zeros(mine.shape, np.uint8)
        cv2.fillPoly(inside, [np.round((outline - [x0, y0]) * 16).astype(np.int32)
                              .reshape(-1, 1, 2)], 1, shift=4)
        both = int(np.count_nonzero(mine & (inside > 0)))
        fits.append(2 * both - int(np.count_nonzero(inside)))
    return int(np.argmax(fits))
