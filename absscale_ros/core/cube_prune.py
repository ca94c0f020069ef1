"""
Which rough cube faces are worth refining, when their colours are already measured.

``detect_cube`` refines every face's sides in three passes on the full-resolution image and
then drops a face whose colour step across a side is under ``min_step``. In the blur retry
and for the pieces of a split region the colours come from an earlier pass, so that test is
known before the refinement: the faces it fails are left out of it (``refine``). Each side
is refined on its own profiles, so the other faces' results do not change.
"""
import numpy as np
import numpy.typing as npt

from absscale_ros.core import sides

Array = npt.NDArray[np.float64]


def refine(image_bgr: npt.NDArray[np.uint8], side_lines: Array, ends: Array, n: int,
           colours: tuple[Array, Array] | None, real: npt.NDArray[np.bool_], min_step: float,
           blurred: bool) -> tuple[npt.NDArray[np.bool_], tuple[Array, ...]]:
    """
    Return (F,) True for the faces refined, and ``sides.refine``'s outputs for all 4F sides
    (zeros for the sides of the faces left out; none at all when every face is).

    :param side_lines: (4F, 3) rough side lines, ``ends`` (4F, 2, 2) their ends px, ``n``
        profiles per side, as ``sides.refine`` takes them.
    :param colours: (4F, 3) inside and outside colours an earlier pass measured, or None
        (then every face is refined, in three passes from the widest band).
    :param real: (F, 4) the sides that must show a colour step (``steps_pass``).
    :param blurred: the blur retry's mid-level sides, two passes (``sides.refine``).
    """
    tried = np.ones(len(real), bool) if colours is None else \
        steps_pass(colours, real, min_step)
    if not tried.any():
        return tried, ()
    rows = np.repeat(tried, 4)
    res = sides.refine(image_bgr, side_lines[rows], ends[rows],
                       (4.0, 2.5) if blurred else (6.0, 4.0, 2.5), n,
                       colours=None if colours is None else (colours[0][rows], colours[1][rows]),
                       blurred=blurred)
    return tried, spread(res, rows)


def steps_pass(colours: tuple[Array, Array], real: npt.NDArray[np.bool_], min_step: float
               ) -> npt.NDArray[np.bool_]:
    """
    Return (F,) True for the faces whose colour step is at least ``min_step`` on every side
    that must show one.

    :param colours: (4F, 3) inside and (4F, 3) outside colours of the faces' sides, as
        ``sides.refine`` takes them (its step is the norm of their difference).
    :param real: (F, 4) True for the sides the step test applies to (not the image border).
    """
    steps = np.linalg.norm(colours[0] - colours[1], axis=1).reshape(-1, 4)
    return np.where(real, steps >= min_step, True).all(axis=1)


def spread(refined: tuple[Array, ...], rows: npt.NDArray[np.bool_]) -> tuple[Array, ...]:
    """
    Return ``sides.refine``'s outputs of the sides ``rows`` (S,) selects, at their places
    among all S sides (zeros for the others, which are never read).
    """
    if rows.all():
        return refined
    out = []
    for a in refined:
        full = np.zeros((len(rows),) + a.shape[1:], a.dtype)
        full[rows] = a
        out.append(full)
    return tuple(out)
