"""Expected failures of absscale_ros, one tree so callers can catch them all at once."""


class AbsScaleError(Exception):
    """Base of every expected failure (bad input, degenerate geometry...)."""


class MessageError(AbsScaleError):
    """A ROS message is malformed or unsupported (bad step, unknown encoding, NaN in K...)."""


class BagError(AbsScaleError):
    """A bag cannot be read or written (missing file, truncated, unknown type...)."""


class DegenerateGeometryError(AbsScaleError):
    """The geometry does not determine the quantity asked for (pure rotation, too few points)."""


class NotObservableError(AbsScaleError):
    """Not enough evidence yet to claim a result (for example no metric scale)."""
