"""
Sheet hypotheses with one corner beyond the image border.

A sheet whose corner lies outside the image is a five-sided region like a sheet with a corner
hidden by an object (``sheet_partial``), the border standing for the occluder's cut: three
corners and two whole sides seen, the two sides at the outside corner seen in part up to the
border. Only the cut along the border is tried, and its corner must lie beyond that border.
The three seen corners fix the sheet's aspect with the intrinsics, so the detector's aspect,
colour and floor-tile tests apply as to a whole sheet (a square tile cut by the border fails
the aspect, a tile between grout the ridge test). The outside corner is an extrapolation and
scores like a hidden one (``vertex_scores``).
"""
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from absscale_ros.core import lines, sheet_candidates, sheet_partial

if TYPE_CHECKING:
    from absscale_ros.core.detect_sheet import SheetConfig

Array = npt.NDArray[np.float64]


def _border_of(p: Array, shape: tuple[int, ...], tol_px: float) -> int | None:
    """Return which border (0 left, 1 top, 2 right, 3 bottom) point ``p`` lies on, or None."""
    gaps = lines.border_gaps(p[None], shape[1], shape[0])[0]
    k = int(np.argmin(gaps))
    return k if gaps[k] <= tol_px else None


def _outside(p: Array, shape: tuple[int, ...], border: int) -> bool:
    """Return True when ``p`` lies beyond ``border`` of the image."""
    return bool(lines.border_gaps(p[None], shape[1], shape[0])[0, border] < 0.0)


def hypotheses(poly: Array, min_seen: float, shape: tuple[int, ...], tol_px: float
               ) -> list[sheet_partial.Partial]:
    """
    Return the hypotheses of a convex pentagon (5, 2), full px, whose cut runs along one image
    border (both its ends within ``tol_px`` of it) and whose fourth corner lies beyond it.
    """
    out = []
    for hyp in sheet_partial.hypotheses(poly, min_seen):
        cut = (hyp.seen_ends[2, 1], hyp.seen_ends[3, 0])
        border = _border_of(cut[0], shape, tol_px)
        if border is None or _border_of(cut[1], shape, tol_px) != border:
            continue
        if _outside(hyp.corners[3], shape, border) and \
                all(_border_of(c, shape, tol_px) is None for c in hyp.corners[:3]):
            out.append(hyp)
    return out


def groups(regions: list[sheet_candidates.Region], work_bgr: npt.NDArray[np.uint8],
           cfg: 'SheetConfig', scale: float, shape: tuple[int, ...]
           ) -> list[list[sheet_partial.Partial]]:
    """
    Return the ``hypotheses`` (full px) of each distinct five-sided region the border cuts
    (work px, ``scale`` times the full image of ``shape``), whitest first: only regions with
    a hypothesis are tested ``plausible`` (most border regions are walls and floor).
    """
    pents: list[Array] = []
    kept: list[tuple[float, list[sheet_partial.Partial]]] = []
    for contour, grow in regions:
        pent = sheet_partial.pentagon(contour)
        pent = None if pent is None else sheet_candidates.offset(pent, grow)
        if pent is None or any(np.abs(pent - q).max() <= 2.0 for q in pents):
            continue
        pents.append(pent)
        hyps = hypotheses(lines.full_px(pent, scale), cfg.min_seen, shape, 2.0 / scale)
        white = sheet_candidates.plausible(work_bgr, contour, cfg) if hyps else None
        if white is not None:
            kept.append((white, hyps))
    return [h for _, h in sorted(kept, key=lambda wh: -wh[0])]
