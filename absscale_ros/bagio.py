"""
Read and write bags without ROS: rosbag2 folders (MCAP or sqlite3) and single ``.mcap`` files.

Messages stay CDR bytes (``BagMessage.data``) so replay never re-encodes them; ``deserialize``
gives rosbags message objects, which ``conversions`` reads like rclpy messages.
"""
from dataclasses import dataclass
from pathlib import Path
import struct
from typing import Any, Iterable, Iterator

from absscale_ros.core.errors import BagError

MCAP_MAGIC = b'\x89MCAP0\r\n'
SQLITE_MAGIC = b'SQLite format 3\x00'


@dataclass(frozen=True)
class TopicInfo:
    msgtype: str
    count: int


@dataclass(frozen=True)
class BagMessage:
    topic: str
    msgtype: str
    stamp_ns: int  # receive/log time in the bag, ns
    data: bytes  # CDR-serialized message


def _typestore() -> Any:
    from rosbags.typesys import get_typestore, Stores
    return get_typestore(Stores.ROS2_JAZZY)


def _check_path(path: Path) -> None:
    """Turn the common ways a bag path is wrong into one clear BagError."""
    if not path.exists():
        raise BagError(f'{path}: no such file or folder')
    if path.is_dir():
        if not (path / 'metadata.yaml').exists():
            raise BagError(f'{path}: folder has no metadata.yaml, so it is not a rosbag2 bag')
        return
    with path.open('rb') as f:
        head = f.read(16)
    if head.startswith(MCAP_MAGIC):
        _check_mcap_tail(path)
        return
    if head.startswith(SQLITE_MAGIC):
        raise BagError(f'{path}: a bare .db3 file; pass the rosbag2 folder holding it and '
                       'its metadata.yaml')
    raise BagError(f'{path}: not a bag (neither an MCAP file nor a rosbag2 folder)')


def _check_mcap_tail(path: Path) -> None:
    size = path.stat().st_size
    with path.open('rb') as f:
        f.seek(max(0, size - len(MCAP_MAGIC)))
        tail = f.read()
    if tail != MCAP_MAGIC:
        raise BagError(f'{path}: MCAP file is truncated or unfinished (no closing magic; '
                       f'{size} bytes)')


class BagReader:
    """
    One bag opened for reading; use as a context manager.

    :param path: rosbag2 folder (MCAP or sqlite3 storage) or a single ``.mcap`` file.
    :raises BagError: when the path is not a readable bag, with the path and the reason.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        _check_path(self.path)
        self._typestore = _typestore()
        self._reader: Any = None

    def __enter__(self) -> 'BagReader':
        from rosbags.highlevel import AnyReader
        try:
            self._reader = AnyReader([self.path], default_typestore=self._typestore)
            self._reader.open()
        except Exception as err:  # rosbags raises many types for the same thing: bad file
            raise BagError(f'{self.path}: cannot open bag: {_one_line(err)}') from err
        return self

    def __exit__(self, *exc: object) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    @property
    def topics(self) -> dict[str, TopicInfo]:
        counts: dict[str, int] = {}
        types: dict[str, str] = {}
        for con in self._reader.connections:
            counts[con.topic] = counts.get(con.topic, 0) + con.msgcount
            types[con.topic] = con.msgtype
        return {t: TopicInfo(types[t], counts[t]) for t in sorted(types)}

    @property
    def start_ns(self) -> int:
        return int(self._reader.start_time)

    @property
    def end_ns(self) -> int:
        # rosbags reports one past the last log time.
        return max(self.start_ns, int(self._reader.end_time) - 1)

    @property
    def duration_ns(self) -> int:
        return max(0, self.end_ns - self.start_ns)

    def messages(self, topics: Iterable[str] | None = None,
                 start_ns: int | None = None) -> Iterator[BagMessage]:
        """Yield messages in log-time order, optionally only ``topics`` and from ``start_ns``."""
        wanted = None if topics is None else set(topics)
        cons = [c for c in self._reader.connections if wanted is None or c.topic in wanted]
        if not cons:
            return
        try:
            for con, stamp_ns, raw in self._reader.messages(connections=cons, start=start_ns):
                yield BagMessage(con.topic, con.msgtype, int(stamp_ns), bytes(raw))
        except Exception as err:
            raise BagError(f'{self.path}: bag is damaged: {_one_line(err)}') from err

    def deserialize(self, msg: BagMessage) -> Any:
        """Return a rosbags message object (readable by ``conversions``)."""
        try:
            return self._typestore.deserialize_cdr(msg.data, msg.msgtype)
        except KeyError as err:
            raise BagError(f'{self.path}: unknown message type {msg.msgtype!r} on '
                           f'{msg.topic}') from err
        except Exception as err:
            raise BagError(f'{self.path}: cannot decode {msg.msgtype} on {msg.topic}: '
                           f'{_one_line(err)}') from err


def open_bag(path: str | Path) -> BagReader:
    """Return an opened ``BagReader`` (still use it as a context manager to close it)."""
    return BagReader(path).__enter__()


def _one_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return f'{type(err).__name__}: {text[0] if text else ""}'.rstrip(': ')


class BagWriter:
    """
    Write CDR messages to a single ``.mcap`` file or, for other paths, a rosbag2 folder.

    :param path: a ``.mcap`` file (must not exist) or a folder (must not exist).
    """

    def __init__(self, path: str | Path, chunk_size: int = 4 * 1024 * 1024) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f'{self.path}: already exists; will not overwrite a bag')
        self._typestore = _typestore()
        self._single = self.path.suffix == '.mcap'
        self._chunk_size = chunk_size
        self._channels: dict[str, Any] = {}
        self._writer: Any = None
        self._file: Any = None

    def __enter__(self) -> 'BagWriter':
        if self._single:
            from mcap.writer import CompressionType, Writer
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._file = self.path.open('wb')
            # JPEG payloads do not compress; zstd would only cost time.
            self._writer = Writer(self._file, chunk_size=self._chunk_size,
                                  compression=CompressionType.NONE)
            self._writer.start(profile='ros2', library='absscale_ros')
        else:
            from rosbags.rosbag2 import StoragePlugin, Writer
            self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
            self._writer.open()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._single:
            self._writer.finish()
            self._file.close()
        else:
            self._writer.close()

    def write(self, topic: str, msgtype: str, stamp_ns: int, data: bytes) -> None:
        """Append one CDR message; ``msgtype`` like ``'sensor_msgs/msg/Image'``."""
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._channels[topic] = self._add_channel(topic, msgtype)
        if self._single:
            self._writer.add_message(channel, log_time=stamp_ns, data=data,
                                     publish_time=stamp_ns)
        else:
            self._writer.write(channel, stamp_ns, data)

    def _add_channel(self, topic: str, msgtype: str) -> Any:
        try:
            msgdef, _ = self._typestore.generate_msgdef(msgtype, ros_version=2)
        except Exception as err:
            raise BagError(f'{self.path}: unknown message type {msgtype!r}') from err
        if not self._single:
            return self._writer.add_connection(topic, msgtype, typestore=self._typestore)
        schema = self._writer.register_schema(name=msgtype, encoding='ros2msg',
                                              data=msgdef.encode())
        return self._writer.register_channel(topic=topic, message_encoding='cdr',
                                             schema_id=schema)


def image_size_of(header: bytes) -> tuple[int, int] | None:
    """Return (width, height) of a JPEG or PNG byte string without decoding it, or None."""
    if header[:8] == b'\x89PNG\r\n\x1a\n' and len(header) >= 24:
        w, h = struct.unpack('>II', header[16:24])
        return int(w), int(h)
    i = 2
    while header[:2] == b'\xff\xd8' and i + 9 < len(header):
        if header[i] != 0xFF:
            return None
        marker = header[i + 1]
        length = struct.unpack('>H', header[i + 2:i + 4])[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            h, w = struct.unpack('>HH', header[i + 5:i + 9])
            return int(w), int(h)
        i += 2 + length
    return None


def header_stamp_ns(data: bytes) -> int | None:
    """
    Return the ``header.stamp`` of a CDR message whose first field is a std_msgs/Header.

    Image, CompressedImage, CameraInfo and PointCloud2 all start with one; reading the stamp
    from the bytes lets replay step on a frame without deserializing megabytes of pixels.
    """
    if len(data) < 12 or data[0] != 0:
        return None
    fmt = '<iI' if data[1] in (1, 3) else '>iI'  # CDR_LE / PL_CDR_LE vs big-endian kinds
    sec, nanosec = struct.unpack_from(fmt, data, 4)
    return int(sec) * 1_000_000_000 + int(nanosec)


class ReplayCursor:
    """
    Walk a bag's messages with one message of look-ahead, optionally looping.

    :param reader: an open ``BagReader``.
    :param topics: topics to replay.
    :param start_ns: first log time to replay, ns.
    """

    def __init__(self, reader: BagReader, topics: Iterable[str], start_ns: int,
                 loop: bool = False) -> None:
        self._reader, self._topics, self._start_ns, self._loop = reader, list(topics), \
            start_ns, loop
        self._iter = reader.messages(self._topics, start_ns=start_ns)
        self._next: BagMessage | None = None
        self.exhausted = False
        self.loops = 0

    def peek(self) -> BagMessage | None:
        if self._next is None and not self.exhausted:
            self._next = next(self._iter, None)
            if self._next is None and self._loop:
                self.loops += 1
                self._iter = self._reader.messages(self._topics, start_ns=self._start_ns)
                self._next = next(self._iter, None)
            self.exhausted = self._next is None
        return self._next

    def take(self) -> BagMessage | None:
        msg = self.peek()
        self._next = None
        return msg
