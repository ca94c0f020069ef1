"""PointCloud2 <-> structured numpy arrays and packed RGB (conversions)."""
import struct

from absscale_ros import conversions
from absscale_ros.core import errors
from conversions_helpers import READERS
from hypothesis import given, settings, strategies as st
import numpy as np
import pytest
from sensor_msgs.msg import PointCloud2, PointField

# PointField datatype -> (struct code, numpy dtype), written out independently of the module.
TYPES = {
    PointField.INT8: ('b', np.int8), PointField.UINT8: ('B', np.uint8),
    PointField.INT16: ('h', np.int16), PointField.UINT16: ('H', np.uint16),
    PointField.INT32: ('i', np.int32), PointField.UINT32: ('I', np.uint32),
    PointField.FLOAT32: ('f', np.float32), PointField.FLOAT64: ('d', np.float64),
}


def random_values(datatype: int, shape: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
    dtype = np.dtype(TYPES[datatype][1])
    if dtype.kind == 'f':
        values = rng.normal(scale=100.0, size=shape).astype(dtype)
        values.reshape(-1)[::5] = np.nan  # clouds that are not dense carry NaNs
        return values
    info = np.iinfo(dtype)
    return rng.integers(info.min, info.max, size=shape, endpoint=True, dtype=dtype)


def hand_made_cloud(layout: list[tuple[str, int, int, int]], point_step: int,
                    values: dict[str, np.ndarray], height: int, width: int, row_pad: int = 0,
                    bigendian: bool = False) -> PointCloud2:
    """
    Build a PointCloud2 byte by byte with struct, the way a C++ driver lays it out.

    :param layout: (name, offset, datatype, count) per field.
    :param values: per field, (height * width, count) values.
    """
    order = '>' if bigendian else '<'
    row_step = width * point_step + row_pad
    data = bytearray(row_step * height)
    for index in range(height * width):
        row, col = divmod(index, width)
        base = row * row_step + col * point_step
        for name, offset, datatype, count in layout:
            fmt = order + TYPES[datatype][0] * count
            struct.pack_into(fmt, data, base + offset, *values[name][index].tolist())
    fields = [PointField(name=name, offset=offset, datatype=datatype, count=count)
              for name, offset, datatype, count in layout]
    return PointCloud2(height=height, width=width, fields=fields, is_bigendian=bigendian,
                       point_step=point_step, row_step=row_step, data=bytes(data),
                       is_dense=False)


def check_fields(points: np.ndarray, layout: list, values: dict[str, np.ndarray]) -> None:
    assert list(points.dtype.names) == [name for name, *_ in layout]
    for name, _, datatype, count in layout:
        column = points[name]
        assert column.dtype.base == np.dtype(TYPES[datatype][1]), name
        assert column.dtype.isnative
        np.testing.assert_array_equal(column.reshape(len(points), count), values[name],
                                      err_msg=name)


@st.composite
def cloud_layouts(draw: st.DrawFn) -> tuple[list, int]:
    """Random fields with random gaps between them and random padding at the end."""
    count_fields = draw(st.integers(1, 5))
    names = ['x', 'y', 'z', 'intensity', 'ring', 'rgb', 'vertex_id']
    chosen = draw(st.permutations(names))[:count_fields]
    layout, offset = [], 0
    for name in chosen:
        datatype = draw(st.sampled_from(sorted(TYPES)))
        count = draw(st.integers(1, 3))
        offset += draw(st.integers(0, 3))
        layout.append((name, offset, datatype, count))
        offset += np.dtype(TYPES[datatype][1]).itemsize * count
    return layout, offset + draw(st.integers(0, 6))


@settings(max_examples=60, deadline=None)
@given(layout_step=cloud_layouts(), height=st.integers(1, 3), width=st.integers(0, 4),
       row_pad=st.integers(0, 7), bigendian=st.booleans(), seed=st.integers(0, 2 ** 16))
def test_any_field_set_padding_and_byte_order_decodes(layout_step: tuple, height: int,
                                                      width: int, row_pad: int,
                                                      bigendian: bool, seed: int) -> None:
    layout, point_step = layout_step
    rng = np.random.default_rng(seed)
    values = {name: random_values(datatype, (height * width, count), rng)
              for name, _, datatype, count in layout}
    msg = hand_made_cloud(layout, point_step, values, height, width, row_pad, bigendian)
    for read in READERS.values():
        points = conversions.cloud_msg_to_array(read(msg))
        assert points.shape == (height * width,)
        check_fields(points, layout, values)


@pytest.mark.parametrize('reader', READERS)
def test_organised_cloud_with_padding_is_flattened_row_major(reader: str) -> None:
    # PCL's PointXYZ layout: 16-byte points (x y z + 4 bytes padding), rows padded too.
    layout = [('x', 0, PointField.FLOAT32, 1), ('y', 4, PointField.FLOAT32, 1),
              ('z', 8, PointField.FLOAT32, 1)]
    grid = np.arange(2 * 3, dtype=np.float32)
    values = {'x': grid[:, None], 'y': -grid[:, None], 'z': grid[:, None] + 0.5}
    msg = READERS[reader](hand_made_cloud(layout, 16, values, 2, 3, row_pad=8))
    points = conversions.cloud_msg_to_array(msg)
    np.testing.assert_array_equal(points['x'], [0, 1, 2, 3, 4, 5])
    np.testing.assert_array_equal(points['z'], grid + 0.5)
    assert points.dtype.itemsize == 16


def test_unpadded_cloud_is_a_view_on_the_message_data() -> None:
    msg = conversions.xyz_rgb_to_cloud_msg(np.zeros((100, 3)))
    points = conversions.cloud_msg_to_array(msg)
    assert np.shares_memory(points, np.frombuffer(msg.data, np.uint8))


@pytest.mark.parametrize('reader', READERS)
def test_nans_are_kept_unless_skipped(reader: str) -> None:
    xyz = np.array([[1, 2, 3], [np.nan, 0, 0], [4, 5, 6], [0, np.inf, 0], [7, 8, np.nan]])
    msg = conversions.xyz_rgb_to_cloud_msg(xyz, extra={'vertex_id': np.arange(5, dtype=np.int32)})
    assert msg.is_dense is False
    msg = READERS[reader](msg)
    assert conversions.cloud_msg_to_array(msg).shape == (5,)
    kept = conversions.cloud_msg_to_array(msg, skip_nans=True)
    np.testing.assert_array_equal(kept['vertex_id'], [0, 2])
    np.testing.assert_array_equal(kept['y'], [2, 5])


@pytest.mark.parametrize('reader', READERS)
def test_structured_array_round_trips_with_subarrays_and_padding(reader: str) -> None:
    dtype = np.dtype({'names': ['x', 'y', 'z', 'normal', 'id', 'flag'],
                      'formats': ['<f8', '<f8', '<f8', ('<f4', (3,)), '<u2', 'i1'],
                      'offsets': [0, 8, 16, 28, 44, 47], 'itemsize': 56})
    rng = np.random.default_rng(3)
    points = np.zeros(7, dtype)
    codes = {'x': PointField.FLOAT64, 'y': PointField.FLOAT64, 'z': PointField.FLOAT64,
             'normal': PointField.FLOAT32, 'id': PointField.UINT16, 'flag': PointField.INT8}
    for name, code in codes.items():
        points[name] = random_values(code, points[name].shape, rng)
    msg = conversions.array_to_cloud_msg(points, stamp_ns=5, frame_id='odom')
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        ('x', 0, PointField.FLOAT64, 1), ('y', 8, PointField.FLOAT64, 1),
        ('z', 16, PointField.FLOAT64, 1), ('normal', 28, PointField.FLOAT32, 3),
        ('id', 44, PointField.UINT16, 1), ('flag', 47, PointField.INT8, 1)]
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (1, 7, 56, 7 * 56)
    assert msg.header.frame_id == 'odom' and msg.is_dense is False
    back = conversions.cloud_msg_to_array(READERS[reader](msg))
    assert back.dtype == dtype
    for name in dtype.names:
        np.testing.assert_array_equal(back[name], points[name], err_msg=name)


def test_big_endian_array_is_written_little_endian() -> None:
    points = np.array([(1.5, 258)], dtype=[('x', '>f4'), ('id', '>u2')])
    msg = conversions.array_to_cloud_msg(points)
    assert msg.is_bigendian is False
    assert bytes(msg.data) == struct.pack('<fH', 1.5, 258)


def test_array_to_cloud_msg_rejects_what_pointcloud2_cannot_carry() -> None:
    with pytest.raises(ValueError, match='structured'):
        conversions.array_to_cloud_msg(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="'label'"):
        conversions.array_to_cloud_msg(np.zeros(3, dtype=[('x', 'f4'), ('label', 'U4')]))
    with pytest.raises(ValueError, match="'big'"):
        conversions.array_to_cloud_msg(np.zeros(3, dtype=[('big', 'i8')]))


# ------------------------------------------------------------------------------------------
# xyz + rgb, packed colours
# ------------------------------------------------------------------------------------------

def test_pack_rgb_follows_the_pcl_convention() -> None:
    packed = conversions.pack_rgb(np.array([[255, 0, 0], [0, 255, 0], [1, 2, 3]], np.uint8))
    assert packed.dtype == np.float32
    np.testing.assert_array_equal(packed.view(np.uint32), [0xFF0000, 0x00FF00, 0x010203])
    np.testing.assert_array_equal(conversions.unpack_rgb(packed), [[255, 0, 0], [0, 255, 0],
                                                                   [1, 2, 3]])


def test_unpack_rgb_ignores_alpha_in_uint32() -> None:
    rgba = np.array([0xFF102030, 0x80FFFFFF], np.uint32)
    np.testing.assert_array_equal(conversions.unpack_rgb(rgba), [[16, 32, 48], [255, 255, 255]])
    # The same bits as float32 are NaNs; unpacking must read bits, not values.
    np.testing.assert_array_equal(conversions.unpack_rgb(rgba.view(np.float32)),
                                  [[16, 32, 48], [255, 255, 255]])


def test_pack_rgb_rejects_bad_colours() -> None:
    with pytest.raises(ValueError, match='256'):
        conversions.pack_rgb(np.array([[0, 256, 0]]))
    with pytest.raises(ValueError, match=r'\(3,\)'):
        conversions.pack_rgb(np.array([1, 2, 3]))


@pytest.mark.parametrize('reader', READERS)
def test_xyz_rgb_cloud_round_trips_with_extra_fields(reader: str) -> None:
    rng = np.random.default_rng(11)
    xyz = rng.normal(size=(50, 3))
    colors = rng.integers(0, 255, size=(50, 3), endpoint=True).astype(np.uint8)
    ids = rng.integers(-5, 1000, size=50).astype(np.int32)
    score = rng.random((50, 2))
    msg = conversions.xyz_rgb_to_cloud_msg(xyz, colors, stamp_ns=10, frame_id='map',
                                           extra={'vertex_id': ids, 'score': score})
    assert [(f.name, f.datatype, f.count) for f in msg.fields] == [
        ('x', PointField.FLOAT32, 1), ('y', PointField.FLOAT32, 1),
        ('z', PointField.FLOAT32, 1), ('rgb', PointField.FLOAT32, 1),
        ('vertex_id', PointField.INT32, 1), ('score', PointField.FLOAT64, 2)]
    assert msg.is_dense is True and msg.header.frame_id == 'map'
    points = conversions.cloud_msg_to_array(READERS[reader](msg))
    np.testing.assert_allclose(np.stack([points['x'], points['y'], points['z']], axis=1), xyz,
                               rtol=1e-6)
    np.testing.assert_array_equal(conversions.unpack_rgb(points['rgb']), colors)
    np.testing.assert_array_equal(points['vertex_id'], ids)
    np.testing.assert_array_equal(points['score'], score)


def test_xyz_rgb_rejects_mismatched_inputs() -> None:
    with pytest.raises(ValueError, match=r'\(N, 3\)'):
        conversions.xyz_rgb_to_cloud_msg(np.zeros((4, 2)))
    with pytest.raises(ValueError, match='colors has 3 rows, points has 4'):
        conversions.xyz_rgb_to_cloud_msg(np.zeros((4, 3)), np.zeros((3, 3), np.uint8))
    with pytest.raises(ValueError, match="'ids' must be"):
        conversions.xyz_rgb_to_cloud_msg(np.zeros((4, 3)), extra={'ids': np.zeros(5)})
    with pytest.raises(ValueError, match="'x' collides"):
        conversions.xyz_rgb_to_cloud_msg(np.zeros((4, 3)), extra={'x': np.zeros(4)})


# ------------------------------------------------------------------------------------------
# Malformed clouds
# ------------------------------------------------------------------------------------------

def xyz_cloud(**fields: object) -> PointCloud2:
    msg = conversions.xyz_rgb_to_cloud_msg(np.ones((4, 3)))
    for name, value in fields.items():
        setattr(msg, name, value)
    return msg


@pytest.mark.parametrize('reader', READERS)
@pytest.mark.parametrize('fields,match', [
    ({'point_step': 8}, r"'z' at offset 8 with 4 bytes does not fit point_step 8"),
    ({'row_step': 40}, r'row_step 40 < width 4 x point_step 12 = 48'),
    ({'data': bytes(47)}, r'47 bytes != row_step 48 x height 1 = 48'),
    ({'height': 2}, r'48 bytes != row_step 48 x height 2 = 96'),
    ({'fields': [PointField(name='x', offset=0, datatype=9, count=1)]}, 'unknown datatype 9'),
    ({'fields': [PointField(name='x', offset=0, datatype=7, count=1),
                 PointField(name='x', offset=4, datatype=7, count=1)]}, r"\['x', 'x'\]"),
])
def test_malformed_clouds_are_rejected_with_numbers(fields: dict, match: str,
                                                    reader: str) -> None:
    with pytest.raises(errors.MessageError, match=match):
        conversions.cloud_msg_to_array(READERS[reader](xyz_cloud(**fields)))


def test_empty_cloud_with_skip_nans() -> None:
    msg = conversions.xyz_rgb_to_cloud_msg(np.zeros((0, 3)), np.zeros((0, 3), np.uint8))
    assert conversions.cloud_msg_to_array(msg, skip_nans=True).shape == (0,)
