"""The metric scale with its uncertainty as a labelled Float64MultiArray."""
from collections.abc import Mapping
from typing import Any

from absscale_ros.core import errors
from std_msgs.msg import Float64MultiArray, MultiArrayDimension


SCALE_LAYOUT = ('factor', 'sigma', 'ci_low', 'ci_high', 'edges', 'objects')


def scale_to_msg(values: Mapping[str, float]) -> Float64MultiArray:
    """
    Return the metric scale as a Float64MultiArray labelled ``factor,sigma,ci_low,...``.

    No standard message holds a scalar with its uncertainty; a labelled array keeps
    ``ros2 topic echo`` readable and needs no custom interface package.
    """
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=','.join(SCALE_LAYOUT),
                                          size=len(SCALE_LAYOUT), stride=len(SCALE_LAYOUT))]
    msg.data = [float(values[k]) for k in SCALE_LAYOUT]
    return msg


def scale_from_msg(msg: Any) -> dict[str, float]:
    """Inverse of :func:`scale_to_msg`; MessageError if the labels are not ours."""
    labels = msg.layout.dim[0].label.split(',') if len(msg.layout.dim) else []
    if labels != list(SCALE_LAYOUT) or len(msg.data) != len(SCALE_LAYOUT):
        raise errors.MessageError(f'scale message has labels {labels}, want {SCALE_LAYOUT}')
    return dict(zip(SCALE_LAYOUT, (float(v) for v in msg.data)))
