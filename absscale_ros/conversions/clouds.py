"""sensor_msgs/PointCloud2 to numpy structured arrays and back (xyz, rgb, normals)."""
from collections.abc import Mapping
import functools
from typing import Any

from absscale_ros.conversions.stamps import bytes_array, set_header, stamp_to_ns
from absscale_ros.core import errors
import numpy as np
import numpy.typing as npt
from sensor_msgs.msg import PointCloud2, PointField


_FIELD_DTYPES: dict[int, np.dtype] = {
    PointField.INT8: np.dtype(np.int8), PointField.UINT8: np.dtype(np.uint8),
    PointField.INT16: np.dtype(np.int16), PointField.UINT16: np.dtype(np.uint16),
    PointField.INT32: np.dtype(np.int32), PointField.UINT32: np.dtype(np.uint32),
    PointField.FLOAT32: np.dtype(np.float32), PointField.FLOAT64: np.dtype(np.float64),
}
_DTYPE_FIELDS = {dtype: code for code, dtype in _FIELD_DTYPES.items()}


def _cloud_dtype(msg: Any) -> np.dtype:
    """Return the structured dtype of one point on the wire (itemsize = point_step)."""
    order = '>' if msg.is_bigendian else '<'
    point_step = int(msg.point_step)
    names, formats, offsets = [], [], []
    for field in msg.fields:
        code, offset, count = int(field.datatype), int(field.offset), int(field.count)
        if code not in _FIELD_DTYPES:
            raise errors.MessageError(f'PointCloud2 field {field.name!r} has unknown datatype '
                                      f'{code} (1..8 are INT8..FLOAT64)')
        base = _FIELD_DTYPES[code].newbyteorder(order)
        # count 0 is written by some drivers for a scalar; ROS means 1 element either way.
        dtype = np.dtype((base, (count,))) if count > 1 else base
        if offset + dtype.itemsize > point_step:
            raise errors.MessageError(
                f'PointCloud2 field {field.name!r} at offset {offset} with {dtype.itemsize} '
                f'bytes does not fit point_step {point_step}')
        names.append(str(field.name))
        formats.append(dtype)
        offsets.append(offset)
    try:
        return np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                         'itemsize': point_step})
    except ValueError as err:  # duplicate or empty names
        raise errors.MessageError(f'PointCloud2 fields {names} are invalid: {err}') from None


def cloud_msg_to_array(msg: Any, skip_nans: bool = False) -> np.ndarray:
    """
    Return a ``sensor_msgs/PointCloud2`` as a structured numpy array.

    :param msg: PointCloud2 from rclpy or rosbags.
    :param skip_nans: drop points whose x, y or z (those present) is not finite; by default
        every point is kept, NaNs included, whatever ``is_dense`` says.
    :returns: (height * width,) array, organised clouds flattened row-major, with the
        message's field names, offsets and dtypes (count > 1 as a subarray) and itemsize
        point_step. Little-endian clouds without row padding are a view on ``msg.data``;
        big-endian ones are copied into native byte order.
    :raises errors.MessageError: on an unknown field type, a field beyond point_step,
        row_step < width x point_step or data length != row_step x height.
    """
    dtype = _cloud_dtype(msg)
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    if row_step < width * point_step:
        raise errors.MessageError(f'PointCloud2 row_step {row_step} < width {width} x '
                                  f'point_step {point_step} = {width * point_step}')
    size = len(msg.data)
    if size != row_step * height:
        raise errors.MessageError(f'PointCloud2 data has {size} bytes != row_step {row_step} '
                                  f'x height {height} = {row_step * height}')
    if height * width == 0:
        points = np.zeros(0, dtype)
    elif point_step == 0:
        raise errors.MessageError(f'PointCloud2 has {height * width} points but point_step 0')
    else:
        rows = np.ndarray((height, width), dtype, buffer=msg.data, strides=(row_step, point_step))
        # reshape copies only when rows are padded; unpadded clouds stay a view.
        points = rows.reshape(-1)
    if msg.is_bigendian:
        points = points.astype(dtype.newbyteorder('='))
    if skip_nans and points.shape[0]:
        keep = np.ones(points.shape[0], dtype=bool)
        for axis in ('x', 'y', 'z'):
            if axis in points.dtype.names:
                values = points[axis]
                keep &= np.isfinite(values.reshape(values.shape[0], -1)).all(axis=1)
        points = points[keep]
    return points


def _fields_from_dtype(dtype: np.dtype) -> list[PointField]:
    # Made once per dtype (~200 us for seven fields: a cloud per frame), shared by the
    # messages (nothing writes to a message's fields).
    return list(_dtype_fields(dtype))


@functools.lru_cache(maxsize=64)
def _dtype_fields(dtype: np.dtype) -> tuple[PointField, ...]:
    fields = []
    for name in dtype.names or ():
        field_dtype, offset = dtype.fields[name][:2]
        base, shape = field_dtype.base, field_dtype.shape
        code = _DTYPE_FIELDS.get(base.newbyteorder('='))
        if code is None or base.names is not None:
            raise ValueError(f'field {name!r} has dtype {field_dtype}, which PointCloud2 '
                             'cannot carry (INT8..FLOAT64 scalars or fixed arrays only)')
        fields.append(PointField(name=name, offset=int(offset), datatype=code,
                                 count=int(np.prod(shape, dtype=np.int64))))
    return tuple(fields)


def array_to_cloud_msg(array: np.ndarray, stamp_ns: int = 0,
                       frame_id: str = 'map') -> PointCloud2:
    """
    Return a structured array as an unorganised PointCloud2 (height 1, little-endian).

    Field offsets and point_step come from the dtype, so padding in it is kept. ``is_dense`` is
    True when every x, y and z present is finite.

    :param array: structured array of any shape (flattened row-major) whose fields are
        INT8..FLOAT64 scalars or fixed-size subarrays (sent with count > 1).
    :raises ValueError: if ``array`` is not structured or a field type has no PointField code.
    """
    points = np.asarray(array)
    if points.dtype.names is None:
        raise ValueError(f'array_to_cloud_msg needs a structured array, got {points.dtype}')
    fields = _fields_from_dtype(points.dtype)
    points = points.reshape(-1).astype(points.dtype.newbyteorder('<'), copy=False)
    msg = PointCloud2()
    set_header(msg, stamp_ns, frame_id)
    msg.height, msg.width = 1, int(points.shape[0])
    msg.fields = fields
    msg.is_bigendian = False
    msg.point_step = int(points.dtype.itemsize)
    msg.row_step = msg.point_step * msg.width
    msg.data = bytes_array(points)
    msg.is_dense = all(bool(np.isfinite(points[axis]).all())
                       for axis in ('x', 'y', 'z') if axis in points.dtype.names)
    return msg


def pack_rgb(colors: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """
    Return (N, 3) uint8 RGB colours packed as PCL does: 0x00RRGGBB bit-cast to float32.

    :raises ValueError: if ``colors`` is not (N, 3) or outside [0, 255].
    """
    colors = np.asarray(colors)
    if colors.ndim != 2 or colors.shape[1] != 3:
        raise ValueError(f'colors must be (N, 3) RGB, got shape {colors.shape}')
    if colors.size and (colors.min() < 0 or colors.max() > 255):
        raise ValueError(f'colors must be in [0, 255], got [{colors.min()}, {colors.max()}]')
    rgb = colors.astype(np.uint32)
    packed = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
    return packed.view(np.float32)


def unpack_rgb(packed: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """
    Return (N, 3) uint8 RGB from PCL-packed colours (float32 bit patterns or uint32).

    The top byte (alpha in 'rgba' fields) is ignored.
    """
    packed = np.asarray(packed).reshape(-1)
    if packed.dtype.kind == 'f':
        if packed.dtype.itemsize != 4:
            raise ValueError(f'packed colours must be float32 or uint32, got {packed.dtype}')
        bits = packed.astype(np.float32, copy=False).view(np.uint32)
    else:
        bits = packed.astype(np.uint32, copy=False)
    shifts = np.array([16, 8, 0], dtype=np.uint32)
    return ((bits[:, None] >> shifts) & 0xFF).astype(np.uint8)


def xyz_rgb_to_cloud_msg(points: npt.ArrayLike, colors: npt.ArrayLike | None = None,
                         stamp_ns: int = 0, frame_id: str = 'map',
                         extra: Mapping[str, npt.ArrayLike] | None = None) -> PointCloud2:
    """
    Return points (and colours and extra fields) as a PointCloud2 RViz can show.

    :param points: (N, 3) positions, m in ``frame_id``; sent as float32 x, y, z.
    :param colors: (N, 3) uint8 RGB, sent as a packed float32 'rgb' field (see
        :func:`pack_rgb`), or None for no colour.
    :param extra: more per-point fields by name, each (N,) or (N, k) of a PointField type,
        e.g. ``{'vertex_id': ids.astype(np.int32)}``.
    :raises ValueError: on shapes that do not match N or names that collide.
    """
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f'points must be (N, 3), got shape {points.shape}')
    n = points.shape[0]
    columns: dict[str, np.ndarray] = {axis: points[:, i].astype(np.float32)
                                      for i, axis in enumerate('xyz')}
    if colors is not None:
        columns['rgb'] = pack_rgb(colors)
    for name, values in (extra or {}).items():
        values = np.asarray(values)
        if name in columns:
            raise ValueError(f'extra field {name!r} collides with a standard field')
        if values.shape[:1] != (n,) or values.ndim > 2:
            raise ValueError(f'extra field {name!r} must be ({n},) or ({n}, k), '
                             f'got {values.shape}')
        columns[name] = values
    if colors is not None and columns['rgb'].shape[0] != n:
        raise ValueError(f'colors has {columns["rgb"].shape[0]} rows, points has {n}')
    dtype = np.dtype([(name, values.dtype, values.shape[1:]) for name, values in columns.items()])
    cloud = np.empty(n, dtype)
    for name, values in columns.items():
        cloud[name] = values
    return array_to_cloud_msg(cloud, stamp_ns=stamp_ns, frame_id=frame_id)


def scaled_cloud_msg(msg: Any, factor: float, stamp_ns: int, frame_id: str) -> PointCloud2:
    """Return ``msg`` with x, y, z multiplied by ``factor``; every other field kept."""
    points = cloud_msg_to_array(msg).copy()
    for axis in ('x', 'y', 'z'):
        if axis not in (points.dtype.names or ()):
            raise errors.MessageError(f'cloud has no {axis!r} field to scale')
        points[axis] = points[axis] * factor
    return array_to_cloud_msg(points, stamp_ns, frame_id)


def dense_cloud_msg(points: npt.ArrayLike, colors: npt.ArrayLike, normals: npt.ArrayLike,
                    stamp_ns: int = 0, frame_id: str = 'map') -> PointCloud2:
    """
    The dense cloud: float32 ``x y z``, packed ``rgb`` and ``normal_x normal_y normal_z``
    (PCL's PointXYZRGBNormal names, which RViz and Open3D's ROS readers know).
    """
    normals = np.asarray(normals, dtype=np.float32)
    if normals.shape != np.shape(points):
        raise ValueError(f'normals {normals.shape} do not match points {np.shape(points)}')
    return xyz_rgb_to_cloud_msg(points, colors, stamp_ns, frame_id, extra={
        f'normal_{a}': normals[:, i] for i, a in enumerate('xyz')})


def cloud_msg_to_xyz_rgb_normals(msg: Any) -> tuple[
        npt.NDArray[np.float64], npt.NDArray[np.uint8] | None, npt.NDArray[np.float64] | None]:
    """Finite points of a PointCloud2 as (N, 3) xyz, and its (N, 3) rgb and normals if any."""
    pts = cloud_msg_to_array(msg, skip_nans=True)
    names = pts.dtype.names or ()
    xyz = np.stack([pts[a] for a in 'xyz'], axis=1).astype(np.float64)
    rgb = unpack_rgb(pts['rgb']) if 'rgb' in names else None
    normals = np.stack([pts[f'normal_{a}'] for a in 'xyz'], axis=1).astype(np.float64) \
        if 'normal_x' in names else None
    return xyz, rgb, normals


def cloud_stamp_and_size(msg: Any) -> tuple[int, int]:
    """(header stamp in ns, number of points) of a PointCloud2, without decoding it."""
    return stamp_to_ns(msg.header.stamp), int(msg.width) * int(msg.height)
