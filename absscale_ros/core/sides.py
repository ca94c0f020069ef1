"""
Sub-pixel refinement of several outline sides at once, on the colour step across each side.

The detectors' last stage: every side of a sheet or of all cube faces of a frame is refined
together, with one ``cv2.remap`` per pass and numpy arrays shaped (sides, profiles, samples).
Along each side, profiles across it sample the full-resolution BGR image; each side's samples
are projected on its own inside-minus-outside colour (so a sheet brighter than the desk on
one side and only differently tinted on another is handled alike, and a red-yellow cube edge
like a red-background one). The edge on a profile is the steepest descent of that projection,
to sub-pixel by a parabola; mixed pixels on an outline are linear blends of the two colours,
so this is the 50% point of the step. A robust (Tukey) total-least-squares line through the
edge points of a side is its refined line, from a coarse band to a fine one.

Lines are ``(a, b, c)`` with unit normal pointing out of the outlined region, as in ``lines``.
"""
from typing import Callable

import cv2
import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.float64]
STEP_PX = 0.5  # sample spacing along a profile
MARGIN = 0.12  # fraction of a side left out at both ends, where the neighbouring side interferes
# A motion-blurred side is searched in a band tens of px wide, but its ramp is 8 px or more:
# samples this many per half band (at least ``STEP_PX`` apart) place its mid-level crossing
# as well, with a third of the samples in a 76 px band (``blur_step``).
BLUR_HALF_SAMPLES = 48


def _project_ends(lines_: Array, ends: Array) -> Array:
    """Return (S, 2, 2) side ends moved onto their lines."""
    dist = np.einsum('sk,sek->se', lines_[:, :2], ends) + lines_[:, None, 2]
    return ends - dist[..., None] * lines_[:, None, :2]


def blur_step(band_px: float) -> float:
    """Return the sample spacing px of a blurred side's profiles (``BLUR_HALF_SAMPLES``)."""
    return max(STEP_PX, band_px / BLUR_HALF_SAMPLES)


def _profiles(image_bgr: npt.NDArray[np.uint8], lines_: Array, ends: Array, band_px: float,
              ns: npt.NDArray[np.int64], step_px: float = STEP_PX
              ) -> tuple[Array, Array, Array]:
    """
    Sample colour profiles across every side, ``ns`` (S,) of them on each (N = the most; a
    side with fewer repeats its last profile: ``_valid`` tells them apart), samples
    ``step_px`` apart.

    :returns: ((S, N, 2) profile centres on the lines, (K,) offsets along the normals,
        (S, N, K, 3) float32 BGR samples).
    """
    q = _project_ends(lines_, ends)
    j = np.minimum(np.arange(ns.max())[None, :], ns[:, None] - 1)
    ts = MARGIN + (1.0 - 2.0 * MARGIN) * (j + 0.5) / ns[:, None]
    centres = q[:, None, 0, :] + ts[:, :, None] * (q[:, 1, :] - q[:, 0, :])[:, None, :]
    offs = np.arange(-band_px, band_px + 1e-9, step_px)
    s, n, k = len(lines_), centres.shape[1], len(offs)
    # Only each side's own profiles are sampled (the repeats are copied: the same values;
    # several candidates of 16-64 profiles in one call are ~45 % repeats).
    if ns.min() == n:
        # (u and v apart: the same sums as on (S, N, K, 2), without the strided copies)
        u, v = (centres[:, :, i, None] + offs * lines_[:, None, None, i] for i in (0, 1))
    else:
        own = _valid(ns)
        side = np.nonzero(own)[0]
        u, v = (centres[own][:, i, None] + offs * lines_[side, i, None] for i in (0, 1))
    samples = cv2.remap(image_bgr, u.reshape(-1, k).astype(np.float32),
                        v.reshape(-1, k).astype(np.float32), cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE).reshape(-1, k, 3).astype(np.float32)
    if ns.min() < n:  # row of (side, profile) in the own ones: the side's first, plus j
        samples = samples[(np.cumsum(ns) - ns)[:, None] + j]
    return centres, offs, samples.reshape(s, n, k, 3)


def _valid(ns: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_]:
    """Return (S, N) True for the profiles each side really has (``_profiles``)."""
    return np.arange(ns.max())[None, :] < ns[:, None]


def _median_strength(strength: Array, ns: npt.NDArray[np.int64]) -> Array:
    """
    Return (S,) the median over each side's own profiles of its edge strengths, leaving out
    the profiles with no edge (strength 0; 0 when a side has none). Profiles past a side's
    count (``_valid``) must be 0 already.
    """
    # A sort-based median of the nonzero entries: np.nanmedian costs ~10x more at this size.
    srt = -np.sort(-strength, axis=1)  # descending: the k edges first
    k = (strength > 0).sum(axis=1)
    rows = np.arange(len(strength))
    lo, hi = np.maximum((k - 1) // 2, 0), np.maximum(k // 2, 0)
    return np.where(k > 0, 0.5 * (srt[rows, lo] + srt[rows, hi]), 0.0)


def _median_profiles(samples: Array) -> Array:
    """
    Return ``np.median(samples, axis=1)`` of (S, N, ...) samples with no NaN (image samples):
    the same values from a sort, which costs a fifth of numpy's partition along that axis.
    """
    srt = np.sort(samples, axis=1)
    n = srt.shape[1]
    if n % 2:
        return srt[:, n // 2]
    return (srt[:, n // 2 - 1] + srt[:, n // 2]) / srt.dtype.type(2)  # np.mean of the two


def side_colours(samples: Array, ns: npt.NDArray[np.int64] | None = None
                 ) -> tuple[Array, Array]:
    """
    Return (S, 3) inside and (S, 3) outside BGR colour of each side: per-channel medians over
    the middle 60% of the profiles, of the first and the last sample (the band's two ends).

    :param ns: (S,) profiles of each side (default: all ``samples.shape[1]``).
    """
    if ns is None:
        ns = np.full(len(samples), samples.shape[1])
    # (the samples' own float32, as a median of them is: the colour step is taken in it)
    inside = np.zeros((len(samples), 3), samples.dtype)
    outside = np.zeros((len(samples), 3), samples.dtype)
    for n in ([ns[0]] if ns.min() == ns.max() else np.unique(ns)):  # usually one count
        idx = np.flatnonzero(ns == n)
        n = int(n)
        # the first and the last sample of the middle profiles (sliced before any copy)
        mid = samples[:, int(0.2 * n):max(int(0.8 * n), int(0.2 * n) + 1), ::samples.shape[2] - 1]
        both = _median_profiles(mid if len(idx) == len(ns) else mid[idx])
        inside[idx], outside[idx] = both[:, 0], both[:, -1]
    return inside, outside


def _project(samples: Array, unit: Array) -> Array:
    """Return (S, N, K) the samples (S, N, K, 3) projected on each side's (S, 3) colour axis."""
    # Channel by channel: the same sums as np.einsum('snkc,sc->snk'), at a third of its cost.
    return (samples[..., 0] * unit[:, 0, None, None] + samples[..., 1] * unit[:, 1, None, None]
            + samples[..., 2] * unit[:, 2, None, None])


def _edges(samples: Array, step: Array, centres: Array, offs: Array, normals: Array
           ) -> tuple[Array, Array]:
    """Return (S, n, 2) steepest-descent edge points and (S, n) strengths (0 = none)."""
    unit = step / np.maximum(np.sqrt((step * step).sum(axis=1, keepdims=True)), 1e-9)
    proj = _project(samples, unit)
    proj = 0.25 * proj[..., :-2] + 0.5 * proj[..., 1:-1] + 0.25 * proj[..., 2:]  # light blur
    drop = proj[..., :-2] - proj[..., 2:]  # positive where it gets darker outwards
    k = np.argmax(drop, axis=2)
    # Flat indexing: take_along_axis costs more than the arithmetic on arrays this small.
    m = drop.shape[2]
    flat, at = drop.reshape(-1, m), np.arange(k.size)
    kf = k.ravel()
    peak = flat[at, kf].reshape(k.shape)
    left = flat[at, np.maximum(kf - 1, 0)].reshape(k.shape)
    right = flat[at, np.minimum(kf + 1, m - 1)].reshape(k.shape)
    den = left - 2.0 * peak + right
    sub = np.where(np.abs(den) > 1e-9, 0.5 * (left - right) / np.where(den == 0, 1, den), 0.0)
    sub = np.minimum(np.maximum(sub, -0.5), 0.5)
    off = offs[2:-2][k] + sub * STEP_PX
    ok = (peak > 0.0) & (k > 0) & (k < drop.shape[2] - 1)
    pts = centres + off[..., None] * normals[:, None, :]
    return pts, np.where(ok, peak, 0.0)


def _mid_edges(samples: Array, step: Array, inside: Array, outside: Array, centres: Array,
               offs: Array, normals: Array) -> tuple[Array, Array]:
    """
    ``_edges`` for an edge smeared by motion blur: the ramp's steepest point wanders over its
    whole length, but a symmetric streak keeps the mid-level crossing on the true edge.
    Strength is the step where the profile starts inside and ends outside, else 0.
    """
    off, ok = _crossings(samples, step, inside, outside, offs, 0.5)
    pts = centres + off[..., None] * normals[:, None, :]
    return pts, np.where(ok, np.linalg.norm(step, axis=1)[:, None], 0.0)


def _crossings(samples: Array, step: Array, inside: Array, outside: Array, offs: Array,
               level: float) -> tuple[Array, Array]:
    """
    Return (S, N) offsets where each profile crosses ``level`` (0 outside .. 1 inside colour)
    and (S, N) True where it starts above and ends below it. The crossing is the mean of the
    first and the last pass through the level: noise crosses it more than once.
    """
    unit = step / np.maximum(np.sqrt((step * step).sum(axis=1, keepdims=True)), 1e-9)
    proj = _project(samples, unit)
    proj = 0.25 * proj[..., :-2] + 0.5 * proj[..., 1:-1] + 0.25 * proj[..., 2:]
    lo = np.einsum('sc,sc->s', outside, unit)[:, None]
    hi = np.einsum('sc,sc->s', inside, unit)[:, None]
    at_level = lo + level * (hi - lo)
    above = proj >= at_level[..., None]
    m = proj.shape[2]
    first = np.argmin(above, axis=2)  # the first sample below the level
    last = m - 1 - np.argmax(above[..., ::-1], axis=2)  # the last one above it

    def cross(k: Array) -> Array:  # sub-sample crossing between samples k and k + 1
        a = np.take_along_axis(proj, k[..., None], axis=2)[..., 0]
        b = np.take_along_axis(proj, np.minimum(k + 1, m - 1)[..., None], axis=2)[..., 0]
        return k + np.clip((a - at_level) / np.where(a - b == 0, 1.0, a - b), 0.0, 1.0)
    at = 0.5 * (cross(np.maximum(first - 1, 0)) + cross(last))
    ok = above[..., 0] & ~above[..., -1] & (first > 0) & (last < m - 1)
    return offs[1] + at * (offs[1] - offs[0]), ok  # ``proj`` starts one sample in


def ramp_widths(image_bgr: npt.NDArray[np.uint8], lines_: Array, ends: Array, band_px: float,
                inside: Array | None, outside: Array | None, n: int = 16,
                step_px: float = STEP_PX) -> Array:
    """
    Return (S,) the distance px between the 25 % and 75 % crossings (from the outside to the
    inside colour) of each side's median profile across it: about half a motion-blur streak
    across the side, a pixel or two at a sharp edge. The median over the profiles along a
    side keeps the texture of the surface around it out. ``inside`` and ``outside`` None: the
    colours at the band's ends (``side_colours``).
    """
    _, offs, samples = _profiles(image_bgr, lines_, ends, band_px, np.full(len(lines_), n),
                                 step_px)
    if inside is None or outside is None:
        inside, outside = side_colours(samples)
    prof = _median_profiles(samples)[:, None]  # (S, 1, K, 3)
    step = inside - outside
    a, ok_a = _crossings(prof, step, inside, outside, offs, 0.75)
    b, ok_b = _crossings(prof, step, inside, outside, offs, 0.25)
    return np.where(ok_a & ok_b, b - a, 0.0)[:, 0]


def fit_lines(pts: Array, weights: Array, outward: Array, scale_px: Array,
              iters: int = 3) -> Array:
    """
    Return (S, 3) robust total-least-squares lines of weighted points (S, n, 2).

    Iteratively reweighted with Tukey's biweight (cut-off 4.685 * ``scale_px`` per side) so
    stray edge samples (text, a cable, another page) do not pull a line; ``outward`` (S, 2)
    orients the normals.
    """
    w = weights.copy()
    # x and y stacked, (2, S, n): one numpy call for both coordinates (each row's sums are
    # the same pairwise sums as on x and y apart).
    xy = np.ascontiguousarray(pts.transpose(2, 0, 1))
    nx = ny = np.zeros(len(pts))
    m = np.zeros((2, len(pts)))
    for it in range(iters):
        sw = np.maximum(w.sum(axis=1), 1e-12)
        m = (w * xy).sum(axis=2) / sw
        d = xy - m[..., None]
        wd = w * d  # (w * dx * dx evaluates as (w * dx) * dx: the same sums)
        cxx, cyy = (wd * d).sum(axis=2)
        cxy = (wd[0] * d[1]).sum(axis=1)
        phi = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)  # direction of largest spread
        nx, ny = -np.sin(phi), np.cos(phi)
        flip = np.where(nx * outward[:, 0] + ny * outward[:, 1] < 0.0, -1.0, 1.0)
        nx, ny = nx * flip, ny * flip
        if it == iters - 1:
            break  # (no weights after the last fit)
        r = (d[0] * nx[:, None] + d[1] * ny[:, None]) / (4.685 * scale_px[:, None])
        w = weights * np.where(np.abs(r) < 1.0, (1.0 - r ** 2) ** 2, 0.0)
    return np.stack([nx, ny, -(nx * m[0] + ny * m[1])], axis=1)


def refine(image_bgr: npt.NDArray[np.uint8], lines_: Array, ends: Array,
           bands_px: tuple[float, ...], n: int | npt.NDArray[np.int64],
           min_rel_strength: float = 0.3,
           colours: tuple[Array, Array] | None = None, blurred: bool = False
           ) -> tuple[Array, Array, Array, Array, Array]:
    """
    Refine S sides on the full-resolution image, coarse band to fine band.

    :param lines_: (S, 3) rough side lines, normals pointing out of the region.
    :param ends: (S, 2, 2) rough side ends px (projected onto the lines).
    :param bands_px: half-widths of the search band, one pass each (the colour step of each
        side is measured in the first, widest one).
    :param n: profiles per side, or (S,) one count per side (several candidates in one call:
        each side gets what it would get alone).
    :param colours: (S, 3) inside and outside colours measured before (by an earlier pass),
        instead of measuring them in the first band.
    :param blurred: edges at the mid level between those colours (``_mid_edges``: motion
        blur), not at the steepest descent, on samples ``blur_step`` apart; support within
        2 px (or 1 % of the side).
    :returns: ((S, 3) refined lines, (S,) support: fraction of profiles whose edge is at least
        ``min_rel_strength`` of the side's median strength and within 1 px (or 0.5% of the
        side) of the refined line, (S,) colour step norm across each side, 0-255 units,
        (S, 3) BGR colour just inside each side, (S, 3) just outside).
    """
    lines_ = lines_.copy()
    ns = np.broadcast_to(np.asarray(n, dtype=np.int64), (len(lines_),))
    valid = _valid(ns)
    length = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
    tol = np.maximum(2.0, 0.01 * length) if blurred else np.maximum(1.0, 0.005 * length)
    step = inside = outside = np.zeros((len(lines_), 3))
    support = np.zeros(len(lines_))
    for i, band in enumerate(bands_px):
        centres, offs, samples = _profiles(image_bgr, lines_, ends, band, ns,
                                           blur_step(band) if blurred else STEP_PX)
        if i == 0:
            inside, outside = side_colours(samples, ns) if colours is None else colours
            step = inside - outside
        if blurred:
            pts, strength = _mid_edges(samples, step, inside, outside, centres, offs,
                                       lines_[:, :2])
        else:
            pts, strength = _edges(samples, step, centres, offs, lines_[:, :2])
        if ns.min() < ns.max():
            strength = np.where(valid, strength, 0.0)
        med = _median_strength(strength, ns)
        keep = (strength > 0) & (strength >= min_rel_strength * med[:, None])
        usable = keep.sum(axis=1) >= 3
        fitted = fit_lines(pts, np.where(keep, strength, 0.0), lines_[:, :2],
                           np.full(len(lines_), max(0.5, band / 4.0)))
        lines_[usable] = fitted[usable]
        if i == len(bands_px) - 1:  # (the last pass's support is the one returned)
            near = np.abs(np.einsum('snk,sk->sn', pts, lines_[:, :2]) + lines_[:, None, 2])
            support = np.where(usable, (keep & (near < tol[:, None])).sum(axis=1) / ns, 0.0)
    return lines_, support, np.linalg.norm(step, axis=1), inside, outside


def ridge_ratio(image_bgr: npt.NDArray[np.uint8], lines_: Array, ends: Array, band_px: float,
                n: int = 16, reaches: tuple[float, ...] = (1.0,)) -> Array:
    """
    Return (S,) how far the colour recovers beyond each refined side: near 0 for a step edge
    (a sheet on a desk: the desk goes on), near 1 for a thin line between two surfaces alike
    (the grout between floor tiles).

    On the median colour profile across a side: the outside colour farthest from the inside
    one (the line, or the surface beyond a step), and ``|far outside - that| / |inside - that|``.
    Colour distances, so a step in tint alone is measured like one in brightness.

    :param band_px: how far inside and outside the profiles reach, px.
    :param reaches: band multiples to measure at, from one sampling; the largest ratio is
        returned (a blurred grout line is wider than the first reach).
    """
    top = max(reaches)
    _, offs, samples = _profiles(image_bgr, lines_, ends, top * band_px,
                                 np.full(len(lines_), n))
    prof = _median_profiles(samples)  # (S, K, 3)
    out = np.zeros(len(lines_))
    for r in reaches:
        band = r * band_px
        inside = np.median(prof[:, (offs < -0.5 * band) & (offs >= -band)], axis=1)
        far = np.median(prof[:, (offs >= 0.6 * band) & (offs <= band)], axis=1)
        near = (offs > 0.5) & (offs <= band)
        k = np.argmax(np.linalg.norm(prof[:, near] - inside[:, None], axis=2), axis=1)
        extreme = prof[:, near][np.arange(len(prof)), k]
        out = np.maximum(out, np.linalg.norm(far - extreme, axis=1)
                         / np.maximum(np.linalg.norm(inside - extreme, axis=1), 1.0))
    return out


Refined = tuple[Array, Array, Array, Array, Array]


def refine_checked(image_bgr: npt.NDArray[np.uint8], lines_: Array, ends: Array,
                   bands_px: tuple[float, ...], n: int, min_first_support: float | Array,
                   checked: npt.NDArray[np.intp] | None = None) -> Refined | None:
    """
    ``refine``, but give up after the first (widest) pass when a side in ``checked`` (default
    all) is supported less than ``min_first_support`` (one value, or one per checked side):
    most candidates are not the object, and the finer passes cost twice the first.
    """
    return refine_many(image_bgr, [lines_], [ends], bands_px, [n], min_first_support,
                       checked)[0]


def refine_many(image_bgr: npt.NDArray[np.uint8], lines_: list[Array], ends: list[Array],
                bands_px: tuple[float, ...], ns: list[int], min_first_support: float | Array,
                checked: npt.NDArray[np.intp] | None | list[npt.NDArray[np.intp] | None] = None,
                screen: Callable[[int, Refined], bool] | None = None,
                blurred: bool = False) -> list[Refined | None]:
    """
    ``refine_checked`` of several candidates (each its (S_c, 3) lines, (S_c, 2, 2) ends and
    profile count) in one ``refine`` call per pass, with the same results: a call costs about
    a millisecond of numpy overhead whatever the number of sides. (Bitwise the same only when
    the candidates share the largest profile count: zero-padded profiles change numpy's
    pairwise summation, so the last bits can differ.) ``checked``: as in
    ``refine_checked``, or a list of one per candidate; ``screen(c, first)``: False drops
    candidate ``c`` after the first pass too; ``blurred``: see ``refine``.
    """
    if not lines_:
        return []
    sizes = [len(ls) for ls in lines_]
    starts = np.cumsum([0] + sizes)
    side_ns = np.repeat(np.asarray(ns, dtype=np.int64), sizes)
    all_ends = np.concatenate(ends)
    first = refine(image_bgr, np.concatenate(lines_), all_ends, bands_px[:1], side_ns,
                   blurred=blurred)

    def part(res: tuple[Array, ...], c: int, at: npt.NDArray[np.int64]) -> Refined:
        a, b = at[c], at[c + 1]
        return res[0][a:b], res[1][a:b], res[2][a:b], res[3][a:b], res[4][a:b]
    keep = []
    for c in range(len(lines_)):
        sup = part(first, c, starts)[1]
        chk = checked[c] if isinstance(checked, list) else checked
        keep.append(bool(((sup if chk is None else sup[chk]) >= min_first_support).all())
                    and (screen is None or screen(c, part(first, c, starts))))
    out: list[Refined | None] = [part(first, c, starts) if k else None
                                 for c, k in enumerate(keep)]
    idx = [c for c, k in enumerate(keep) if k]
    if len(bands_px) == 1 or not idx:
        return out
    rows = np.concatenate([np.arange(starts[c], starts[c + 1]) for c in idx])
    second = refine(image_bgr, first[0][rows], all_ends[rows], bands_px[1:], side_ns[rows],
                    colours=(first[3][rows], first[4][rows]), blurred=blurred)
    at = np.cumsum([0] + [sizes[c] for c in idx])
    for j, c in enumerate(idx):
        out[c] = part(second, j, at)
    return out
