"""
A sheet that an object standing on it cuts in two: its hidden corner from both parts.

Seen from low, a box on one corner of a page can hide that corner and the middle of a side
next to it, so the page shows as a large region and a small one beyond the box holding
another corner (``sheet_candidates``: a region joined with a small part near it). The two
parts' joint outline is the five-sided outline of ``sheet_partial``, with one difference:
the side that runs under the box between the parts is seen only at its two ends. Its colours
and its support are therefore judged on the stretches where the sheet's colour shows just
inside it, not on its middle, which is the box's.
"""
import numpy as np
import numpy.typing as npt

from absscale_ros.core import sheet_partial, sides

Array = npt.NDArray[np.float64]
SAMPLES = 64  # colour samples along each side
MIN_SHOWN = 0.2  # of a side: the least that must show the sheet's colour inside it
NARROW_SHOWN = 0.9  # of a side: less shown than this, it is refined where shown (``narrowed``)
SPAN = (0.1, 0.9)  # the part of each side sampled, clear of its corners (``shown``)
_TS = np.linspace(*SPAN, SAMPLES)
_NEXT = np.array([1, 2, 3, 0])
GO_ON_CONTRAST = 20.0  # BGR distance below which the colour is the sheet's
INSIDE_PX = 3.0  # how far inside a side its colour is sampled along it


def shown(image_bgr: npt.NDArray[np.uint8], corners: Array, lines_: Array,
          colour: Array | None = None) -> tuple[Array, Array]:
    """
    Return (4,) the fraction of each side (between its corners, clear of them by a tenth)
    along which the colour just inside it is the sheet's ``colour`` (BGR; None: the median
    of those samples over all four sides), and (4, 2, 2) where on each side the first
    stretch showing it ends and the last one begins.
    """
    frac, runs = shown_many(image_bgr, corners[None], lines_[None],
                            None if colour is None else colour[None])
    return frac[0], runs[0]


def shown_many(image_bgr: npt.NDArray[np.uint8], corners: Array, lines_: Array,
               colours: Array | None = None) -> tuple[Array, Array]:
    """``shown`` of M quadrilaterals (M, 4, 2) with their (M, 4, 3) side lines (and (M, 3)
    colours) at once, bit for bit: (M, 4) and (M, 4, 2, 2)."""
    h, w = image_bgr.shape[:2]
    ts, ends = _TS, corners[:, _NEXT]
    pts = corners[:, :, None] + ts[None, None, :, None] * (ends - corners)[:, :, None] \
        - INSIDE_PX * lines_[:, :, None, :2]
    u = np.clip(np.round(pts[..., 0]).astype(int), 0, w - 1)
    v = np.clip(np.round(pts[..., 1]).astype(int), 0, h - 1)
    bgr = image_bgr[v, u].astype(np.float64)  # (M, 4, SAMPLES, 3)
    # (np.median and np.linalg.norm written out: the same values at a third of the cost)
    if colours is None:
        srt = np.sort(bgr.reshape(len(bgr), -1, 3), axis=1)
        n = srt.shape[1]
        colours = (srt[:, (n - 1) // 2] + srt[:, n // 2]) / 2.0
    d = bgr - colours[:, None, None]
    ok = np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2]) \
        < GO_ON_CONTRAST
    # The first and the last run of samples showing the sheet (where its edges change): where
    # the first run ends and where the last begins.
    padded = np.zeros(ok.shape[:2] + (SAMPLES + 2,), np.int8)
    padded[..., 1:-1] = ok
    change = padded[..., 1:] - padded[..., :-1]
    first_end = np.argmax(change == -1, axis=2) - 1  # (-1 and SAMPLES where none shows)
    last_start = np.minimum(SAMPLES - np.argmax(change[..., ::-1] == 1, axis=2), SAMPLES - 1)
    runs = corners[:, :, None] + ts[np.stack([first_end, last_start], axis=2)][..., None] \
        * (ends - corners)[:, :, None]
    seen = np.count_nonzero(ok, axis=2)
    return seen / SAMPLES, np.where(seen[..., None, None] > 0, runs, 0.0)


def narrowed(hyp: sheet_partial.Partial, image_bgr: npt.NDArray[np.uint8]
             ) -> sheet_partial.Partial:
    """
    Return ``hyp`` with the side under the object (of the two between seen corners, the one
    less shown inside its rough line) refined only along its longer stretch shown at an
    end, when it shows the sheet's colour over less than ``NARROW_SHOWN`` of its length:
    refined along all of it, the side follows the object's foot and moves the corners at
    its ends by several pixels (seed 57, frame 200: 18 % off the sheet's aspect).
    """
    return narrowed_many([hyp], image_bgr)[0]


def narrowed_many(hyps: list[sheet_partial.Partial], image_bgr: npt.NDArray[np.uint8]
                  ) -> list[sheet_partial.Partial]:
    """``narrowed`` of many hypotheses, their ``shown`` measured together (bit for bit)."""
    if not hyps:
        return []
    corners = np.array([h.corners for h in hyps])
    fracs, runs_all = shown_many(image_bgr, corners,
                                 np.array([sheet_partial.rough_sides(h)[0] for h in hyps]))
    return [_narrowed(h, f, r) for h, f, r in zip(hyps, fracs, runs_all)]


def _narrowed(hyp: sheet_partial.Partial, frac: Array, runs: Array) -> sheet_partial.Partial:
    """``narrowed`` given ``shown`` of its rough sides."""
    gap = int(np.argmin(frac[:2]))
    if frac[gap] >= NARROW_SHOWN or frac[gap] < MIN_SHOWN:
        return hyp
    a, b = hyp.corners[gap], hyp.corners[gap + 1]
    # A stretch from a corner to where the first run shown ends (or from where the last
    # begins): no longer than all the samples shown and the unsampled end, else it spans
    # the gap (one run only).
    most = (SPAN[0] + (SPAN[1] - SPAN[0]) * frac[gap] + 0.05) * np.hypot(*(b - a))
    ends_ok = [e for e in (np.array([a, runs[gap, 0]]), np.array([runs[gap, 1], b]))
               if np.hypot(*(e[1] - e[0])) <= most]
    if not ends_ok:
        return hyp
    ends = hyp.seen_ends.copy()
    ends[gap] = max(ends_ok, key=lambda e: float(np.hypot(*(e[1] - e[0]))))
    return sheet_partial.Partial(hyp.corners, ends, hyp.seen_frac, hyp.outline)


def finish(hyp: sheet_partial.Partial, out: sides.Refined, band_px: float,
           image_bgr: npt.NDArray[np.uint8]
           ) -> tuple[Array, ...] | None:
    """
    ``sheet_partial.finish`` of a hypothesis from the joined parts, (4, 2, 2) the seen side
    ends for the floor-tile test and the seen outline's two parts (a tuple of (M, 2)). Of
    the two sides between seen corners, the one less shown (``shown``) runs under the
    object: its support is taken over the part shown, the other sides' colours and colour
    step stand in for its own in the one-colour and contrast tests, and the floor-tile test
    looks beside its first stretch shown. The rough hidden corner comes from the small
    part's rough outline, so it may move as much more as the side seen there is short.
    """
    res = sheet_partial.finish(hyp, out, band_px, 1.0 / float(hyp.seen_frac.min()))
    if res is None:
        return None
    corners, supports, steps, inside, outside, outline = res
    frac, runs = shown(image_bgr, corners, out[0], np.median(inside, axis=0))
    gap = int(np.argmin(frac[:2]))  # of the sides between seen corners (2 and 3 end hidden)
    if frac[gap] < MIN_SHOWN:
        return None
    rest = np.delete(np.arange(4), gap)
    supports, steps = supports.copy(), steps.copy()
    inside, outside, seen = inside.copy(), outside.copy(), hyp.seen_ends.copy()
    if np.array_equal(hyp.seen_ends[gap], hyp.corners[gap:gap + 2]):  # not ``narrowed``
        supports[gap] = min(1.0, supports[gap] / frac[gap])
    steps[gap] = np.median(steps[rest])
    inside[gap], outside[gap] = np.median(inside[rest], axis=0), np.median(outside[rest], axis=0)
    # The floor-tile test beside the first stretch shown, not beside the box; the seen
    # outline in two parts, the box between them left out.
    seen[gap] = [corners[gap], runs[gap, 0]]
    cut = np.array([outline[3], outline[4]])  # on sides 2 and 3
    if gap == 1:
        parts = (np.array([corners[0], corners[1], runs[1, 0], cut[1]]),
                 np.array([runs[1, 1], corners[2], cut[0]]))
    else:
        parts = (np.array([cut[1], corners[0], runs[gap, 0]]),
                 np.array([runs[gap, 1], corners[1], corners[2], cut[0]]))
    return corners, supports, steps, inside, outside, outline, seen, parts
