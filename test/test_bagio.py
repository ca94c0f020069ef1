"""bagio reads what it writes, in both layouts, and what rosbags writes as sqlite3."""
from pathlib import Path

from absscale_ros import bagio
from bagfactory import IMAGE_TOPIC, INFO_TOPIC, write_camera_bag
import pytest


@pytest.mark.parametrize('name', ['single.mcap', 'folder_bag'])
def test_write_then_read_back(tmp_path: Path, name: str) -> None:
    sent = write_camera_bag(tmp_path / name, frames=5)
    with bagio.BagReader(tmp_path / name) as reader:
        assert reader.topics[IMAGE_TOPIC] == bagio.TopicInfo('sensor_msgs/msg/CompressedImage', 5)
        assert reader.topics[INFO_TOPIC].count == 5
        got = [m.data for m in reader.messages([IMAGE_TOPIC])]
        assert got == sent
        first = next(reader.messages([IMAGE_TOPIC]))
        assert bagio.header_stamp_ns(first.data) == first.stamp_ns - 1
        assert reader.deserialize(first).format.startswith('bgr8; jpeg')
        assert reader.duration_ns == 4 * 33_333_333 + 1


def test_sqlite3_rosbag2_folder(tmp_path: Path) -> None:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import get_typestore, Stores
    src = tmp_path / 'src.mcap'
    sent = write_camera_bag(src, frames=3)
    store = get_typestore(Stores.ROS2_JAZZY)
    writer = Writer(tmp_path / 'sq', version=8, storage_plugin=StoragePlugin.SQLITE3)
    writer.open()
    con = writer.add_connection(IMAGE_TOPIC, 'sensor_msgs/msg/CompressedImage', typestore=store)
    for i, data in enumerate(sent):
        writer.write(con, 10 + i, data)
    writer.close()
    with bagio.BagReader(tmp_path / 'sq') as reader:
        assert [m.data for m in reader.messages()] == sent


def test_writer_refuses_to_overwrite(tmp_path: Path) -> None:
    write_camera_bag(tmp_path / 'a.mcap', frames=1)
    with pytest.raises(bagio.BagError, match='already exists'):
        bagio.BagWriter(tmp_path / 'a.mcap')


def test_loop_cursor_restarts(tmp_path: Path) -> None:
    write_camera_bag(tmp_path / 'a.mcap', frames=2)
    with bagio.BagReader(tmp_path / 'a.mcap') as reader:
        cursor = bagio.ReplayCursor(reader, [IMAGE_TOPIC], reader.start_ns, loop=True)
        stamps = [cursor.take().stamp_ns for _ in range(5)]
        assert stamps[0] == stamps[2] == stamps[4] and cursor.loops == 2
