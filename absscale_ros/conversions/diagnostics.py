"""diagnostic_msgs and the lossless replay's acknowledgement headers."""
from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import Any

from absscale_ros.conversions.stamps import ns_to_stamp, set_header, stamp_to_ns
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from std_msgs.msg import Header


_LEVELS = {'ok': DiagnosticStatus.OK, 'warn': DiagnosticStatus.WARN,
           'error': DiagnosticStatus.ERROR, 'stale': DiagnosticStatus.STALE}


def _level_byte(level: str | bytes | int) -> bytes:
    if isinstance(level, str):
        if level.lower() not in _LEVELS:
            raise ValueError(f'diagnostic level must be one of {list(_LEVELS)}, got {level!r}')
        return _LEVELS[level.lower()]
    value = level[0] if isinstance(level, bytes) and len(level) == 1 else level
    if not isinstance(value, int) or not 0 <= value <= 3:
        raise ValueError(f'diagnostic level must be 0..3 (OK..STALE), got {level!r}')
    return bytes([value])


def _format_value(value: object) -> str:
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (float, np.floating)):
        return format(float(value), '.6g')  # compact: 0.1 not 0.1000000000000000055...
    if isinstance(value, np.integer):
        return str(int(value))
    return str(value)


def diagnostic_status(name: str, level: str | bytes | int, message: str,
                      values: Mapping[str, object] = MappingProxyType({}),
                      hardware_id: str = 'absscale') -> DiagnosticStatus:
    """
    Return a ``diagnostic_msgs/DiagnosticStatus``.

    :param level: 'ok', 'warn', 'error' or 'stale', or the message's byte constants
        (``DiagnosticStatus.OK``...) or their integer values.
    :param values: key/value pairs; floats are written with 6 significant digits.
    :raises ValueError: on an unknown level.
    """
    return DiagnosticStatus(
        level=_level_byte(level), name=name, message=message, hardware_id=hardware_id,
        values=[KeyValue(key=str(key), value=_format_value(value))
                for key, value in values.items()])


def diagnostic_array(statuses: Sequence[DiagnosticStatus], stamp_ns: int) -> DiagnosticArray:
    """Return statuses in a ``diagnostic_msgs/DiagnosticArray`` stamped ``stamp_ns``."""
    msg = DiagnosticArray()
    set_header(msg, stamp_ns, '')
    msg.status = list(statuses)
    return msg


def diagnostic_summary(msg: Any) -> dict[str, dict[str, Any]]:
    """Status name -> ``{level (int 0..3), message, values}`` of a DiagnosticArray."""
    return {str(st.name): {'level': _level_byte(st.level)[0], 'message': str(st.message),
                           'values': diagnostic_values(st)} for st in msg.status}


def ack_to_msg(text: str, stamp: Any) -> Header:
    """The step-mode acknowledgement ``text`` (see core/replay.Ack) for a message's stamp."""
    return Header(stamp=stamp, frame_id=text)


def end_of_bag_msg(stamp_ns: int) -> Header:
    """The lossless replay's end-of-bag message, stamped after every frame (``bag_replay``)."""
    return Header(stamp=ns_to_stamp(stamp_ns), frame_id='end_of_bag')


def ack_from_msg(msg: Any) -> tuple[str, int]:
    """Inverse of :func:`ack_to_msg`: (text, stamp in ns)."""
    return str(msg.frame_id), stamp_to_ns(msg.stamp)


def diagnostic_values(status: Any) -> dict[str, str]:
    """Return a DiagnosticStatus's key/value pairs as a dict (the last one wins on repeats)."""
    return {str(pair.key): str(pair.value) for pair in status.values}
