"""
Recordings that ROS tools replay: a rosbag2 folder with MCAP storage, split by time.

``BagRecorder(path)`` creates ``path/`` holding ``metadata.yaml`` and ``<name>_0.mcap``,
``<name>_1.mcap``, ... (the layout ``ros2 bag record -s mcap --max-bag-duration`` writes),
with ROS 2 CDR messages and ``ros2msg`` schemas (``sm_ros.bag_meta``), written with the
MCAP library for Python (``pip install '.[record]'``). So ``ros2 bag info``/``ros2 bag
play``, Foxglove, ``rosbags`` and the ``mcap`` reader open it.

Ticks never wait for the disk: ``write(topic, type, data, stamp_ns)`` puts the already
serialised message on a bounded queue (by count and by bytes) and returns; a background
thread writes. When the queue is full the message is dropped and counted (``dropped``,
reported by the node's diagnostics as ``recorder_dropped``).

A run that stops at any moment leaves files that can be read:

- every ``split_s`` seconds of log time the open file is finished (last chunk, summary,
  footer: any reader opens it) and listed in ``metadata.yaml``, rewritten whole, and the
  next file is opened; ``metadata.yaml`` lists finished files only, so after a SIGKILL or
  a power loss every reader opens the recording as it stands, less the last ``split_s``;
- stopping (service, parameter, Ctrl-C, SIGTERM, the end of the process) finishes the open
  file too;
- at least every ``flush_s`` seconds the open file's chunk is closed and flushed, so the
  messages of a file cut short by a crash read with MCAP's streaming reader (``iter_raw``)
  and ``python -m sm_ros.record repair BAG`` (like ``ros2 bag reindex``) rewrites it with
  its summary and lists it in ``metadata.yaml``.

Command line::

    python -m sm_ros.record info BAG      # topics, counts, time span (needs mcap)
    python -m sm_ros.record repair BAG    # after a crash: finish the open file, metadata
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import queue
import re
import sys
import threading
import time
from typing import Dict, Iterator, List, Optional, Sequence, Tuple

from sm_ros.bag_meta import (_normalize, _QOS_V8, add_message, message_definition,  # noqa: F401
                             metadata_dict, msg_file, new_file_info, write_metadata)

#: Last bytes of a finished MCAP file (its magic after the footer).
_MAGIC = b'\x89MCAP0\r\n'


class RecordUnavailable(RuntimeError):
    """mcap is not installed (``pip install 'sm_ros[record]'``)."""


def _mcap():
    try:
        from mcap import writer
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise RecordUnavailable(
            "recording needs the MCAP library: pip install -e '.[record]'") from exc
    return writer


# ----------------------------------------------------------------------------------------
# The recorder
# ----------------------------------------------------------------------------------------

class BagRecorder:
    """
    Record serialised ROS 2 messages into a rosbag2 (MCAP) folder on a background thread.

    ``path`` must not exist yet (like ``ros2 bag record -o``). ``split_s`` is the log time
    each file spans before the next one opens (0: one file); ``max_queue`` and
    ``max_queue_bytes`` bound what waits for the disk; ``chunk_bytes`` is the MCAP chunk
    size; ``compression`` is '' (none: no CPU taken from the solver) or 'zstd'.
    """

    def __init__(self, path, max_queue: int = 256, max_queue_bytes: int = 512 << 20,
                 chunk_bytes: int = 4 << 20, flush_s: float = 1.0, compression: str = '',
                 split_s: float = 10.0):
        """Create the folder, open the first MCAP file and start the writer thread."""
        self._mod = _mcap()
        self.path = Path(path)
        if self.path.exists():
            raise FileExistsError(f'{self.path} exists already (recordings are never '
                                  'overwritten)')
        if compression not in ('', 'zstd', 'lz4'):
            raise ValueError(f"compression must be '', 'zstd' or 'lz4', got '{compression}'")
        if not split_s >= 0.0:
            raise ValueError(f'split_s must be >= 0, got {split_s}')
        self.path.mkdir(parents=True)
        self._compression = {'': self._mod.CompressionType.NONE,
                             'zstd': self._mod.CompressionType.ZSTD,
                             'lz4': self._mod.CompressionType.LZ4}[compression]
        self._chunk_bytes = int(chunk_bytes)
        self._split_ns = int(split_s * 1e9)
        self.files: List[dict] = []          # finished files (metadata.yaml lists them)
        self.topics: Dict[str, str] = {}
        self.counts: Dict[str, int] = {}
        self.start_ns: Optional[int] = None
        self.end_ns = 0
        self.dropped = 0
        self.written = 0
        self.error: Optional[str] = None
        self._queue: queue.Queue = queue.Queue(maxsize=int(max_queue))
        self._queued_bytes = 0
        self._max_bytes = int(max_queue_bytes)
        self._lock = threading.Lock()
        self._flush_s = float(flush_s)
        self._closed = False
        self._open_file()
        write_metadata(self.path, metadata_dict([]))
        self._thread = threading.Thread(target=self._run, name='sm_ros-recorder', daemon=True)
        self._thread.start()

    @property
    def mcap_name(self) -> str:
        """The name of the file being written."""
        return self._info['path']

    # ------------------------------------------------------------------ producer side

    def write(self, topic: str, msgtype: str, data, stamp_ns: int,
              publish_ns: Optional[int] = None) -> bool:
        """
        Queue one serialised (CDR) message; return False if it was dropped.

        ``stamp_ns`` is the log time (the time it was recorded, as ``ros2 bag record``
        stores it; replay follows it); ``publish_ns`` the message's own time (the node
        gives its simulation time; default: ``stamp_ns``). ``data`` must not change
        afterwards (``bytes`` from ``serialize_message``).
        """
        if self._closed:
            return False
        n = len(data)
        with self._lock:
            if self._queued_bytes + n > self._max_bytes:
                self.dropped += 1
                return False
            self._queued_bytes += n
        try:
            self._queue.put_nowait((topic, msgtype, data, int(stamp_ns),
                                    int(stamp_ns if publish_ns is None else publish_ns)))
        except queue.Full:
            with self._lock:
                self._queued_bytes -= n
                self.dropped += 1
            return False
        return True

    @property
    def queued(self) -> int:
        """Return the number of messages waiting for the writer thread."""
        return self._queue.qsize()

    # ------------------------------------------------------------------ writer thread

    def _open_file(self) -> None:
        """Open the next ``<name>_<i>.mcap``; its schemas and channels start afresh."""
        self._info = new_file_info(f'{self.path.name}_{len(self.files)}.mcap')
        self._file = open(self.path / self._info['path'], 'wb')
        self._writer = self._mod.Writer(self._file, chunk_size=self._chunk_bytes,
                                        compression=self._compression)
        self._writer.start(profile='ros2', library='sm_ros')
        self._channels: Dict[str, int] = {}
        self._schemas: Dict[str, int] = {}

    def _finish_file(self) -> None:
        """Finish the open file (summary, footer) and list it in metadata.yaml."""
        import yaml
        try:
            info = metadata_dict(self.files + [self._info])['rosbag2_bagfile_information']
            self._writer.add_metadata('rosbag2', {'serialized_metadata': yaml.safe_dump(
                info, default_flow_style=False, sort_keys=False)})
            self._writer.finish()
        finally:
            self._file.close()
        self.files.append(self._info)
        write_metadata(self.path, metadata_dict(self.files))

    def _channel(self, topic: str, msgtype: str) -> int:
        cid = self._channels.get(topic)
        if cid is not None:
            return cid
        sid = self._schemas.get(msgtype)
        if sid is None:
            pkg, _, name = _normalize(msgtype).partition('/msg/')
            sid = self._writer.register_schema(
                name=f'{pkg}/msg/{name}', encoding='ros2msg',
                data=message_definition(msgtype).encode('utf-8'))
            self._schemas[msgtype] = sid
        import yaml
        qos = yaml.safe_dump(_QOS_V8, default_flow_style=False).strip()
        cid = self._writer.register_channel(topic=topic, message_encoding='cdr',
                                            schema_id=sid,
                                            metadata={'offered_qos_profiles': qos})
        self._channels[topic] = cid
        self.topics.setdefault(topic, _normalize(msgtype))
        self.counts.setdefault(topic, 0)
        return cid

    def _add(self, topic: str, msgtype: str, data, stamp: int, pub: int) -> None:
        """Write one message, into a new file when the open one spans ``split_s``."""
        first = self._info['start']
        if self._split_ns and first is not None and stamp - first >= self._split_ns:
            self._finish_file()
            self._open_file()
        cid = self._channel(topic, msgtype)
        seq = self.counts[topic]
        self._writer.add_message(channel_id=cid, log_time=stamp, data=data,
                                 publish_time=pub, sequence=seq)
        self.counts[topic] = seq + 1
        add_message(self._info, topic, self.topics[topic], stamp)
        self.written += 1
        if self.start_ns is None or stamp < self.start_ns:
            self.start_ns = stamp
        self.end_ns = max(self.end_ns, stamp)

    def _run(self) -> None:
        last_flush = time.monotonic()
        while True:
            try:
                item = self._queue.get(timeout=self._flush_s)
            except queue.Empty:
                item = None
            if item is not None and item[0] is None:
                break
            if item is not None:
                with self._lock:
                    self._queued_bytes -= len(item[2])
                if self.error is None:
                    try:
                        self._add(*item)
                    except Exception as exc:  # noqa: BLE001 - disk full, bad type: stop
                        self.error = f'{type(exc).__name__}: {exc}'
                else:
                    self.dropped += 1
            now = time.monotonic()
            if now - last_flush >= self._flush_s and self.error is None:
                self._flush()
                last_flush = now

    def _metadata(self) -> dict:
        """metadata.yaml: the finished files; the open one named in custom_data."""
        if self._closed and self._info in self.files:
            return metadata_dict(self.files)
        return metadata_dict(self.files, {
            'open_file': self._info['path'],
            'open_file_messages': str(sum(self._info['counts'].values()))})

    def _flush(self) -> None:
        try:
            self._writer.flush()
            self._file.flush()
            write_metadata(self.path, self._metadata())
        except Exception as exc:  # noqa: BLE001
            self.error = f'{type(exc).__name__}: {exc}'

    # ------------------------------------------------------------------ stop

    def close(self, timeout: float = 30.0) -> dict:
        """Write what is queued, finish the open file, write metadata.yaml; return it."""
        if self._closed:
            return self._metadata()
        self._closed = True
        self._queue.put((None, None, None, 0, 0))
        self._thread.join(timeout)
        self._finish_file()
        meta = self._metadata()
        write_metadata(self.path, meta)
        return meta

    def __enter__(self):
        """Use as a context manager: closed on exit."""
        return self

    def __exit__(self, *exc):
        """Close the recording."""
        self.close()


# ----------------------------------------------------------------------------------------
# Reading back (no ROS needed) and repair
# ----------------------------------------------------------------------------------------

def mcap_paths(bag) -> List[Path]:
    """Return the .mcap files of a bag folder in recording order (or the file itself)."""
    p = Path(bag)
    if p.is_file():
        return [p]

    def index(f: Path):
        m = re.search(r'_(\d+)$', f.stem)
        return (int(m.group(1)) if m else -1, f.name)
    files = sorted(p.glob('*.mcap'), key=index)
    if not files:
        raise FileNotFoundError(f'{p}: no .mcap file (is it a rosbag2 MCAP folder?)')
    return files


def mcap_path(bag) -> Path:
    """Return the first .mcap file of a bag folder (or the file itself)."""
    return mcap_paths(bag)[0]


def iter_raw(bag, topics: Optional[Sequence[str]] = None, publish_time: bool = False
             ) -> Iterator[Tuple[str, str, int, bytes]]:
    """
    Yield (topic, schema name, log time ns, CDR bytes) in file order, file after file
    (with ``publish_time``: (topic, schema name, log time, CDR bytes, publish time)).

    Reads records one after the other (no index needed), so a file that was cut short by
    a crash is read up to its last complete chunk.
    """
    for path in mcap_paths(bag):
        yield from _iter_file(path, topics, publish_time)


def _iter_file(path: Path, topics, publish_time: bool):
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader
    schemas: Dict[int, str] = {}
    channels: Dict[int, Tuple[str, str]] = {}
    with open(path, 'rb') as f:
        reader = StreamReader(f, record_size_limit=None)
        try:
            for rec in reader.records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec.name
                elif isinstance(rec, Channel):
                    channels[rec.id] = (rec.topic, schemas.get(rec.schema_id, ''))
                elif isinstance(rec, Message):
                    topic, schema = channels[rec.channel_id]
                    if topics is None or topic in topics:
                        if publish_time:
                            yield topic, schema, rec.log_time, rec.data, rec.publish_time
                        else:
                            yield topic, schema, rec.log_time, rec.data
        except (McapError, EOFError, ValueError, OSError, KeyError):
            return   # a file cut short: everything before the cut was yielded


def finished(path: Path) -> bool:
    """Whether an MCAP file ends with its footer's magic (its writer finished it)."""
    with open(path, 'rb') as f:
        f.seek(0, os.SEEK_END)
        if f.tell() < 2 * len(_MAGIC):
            return False
        f.seek(-len(_MAGIC), os.SEEK_END)
        return f.read() == _MAGIC


def repair(bag) -> dict:
    """
    Make a bag whose writer was killed whole: every file left unfinished is rewritten
    with its complete messages into a finished, indexed file, and metadata.yaml lists
    every file with its true counts. Returns the new metadata.
    """
    files = []
    for path in mcap_paths(bag):
        if not finished(path):
            _rewrite(path)
        info = new_file_info(path.name)
        for topic, schema, stamp, _ in _iter_file(path, None, False):
            add_message(info, topic, schema, stamp)
        files.append(info)
    meta = metadata_dict(files)
    if Path(bag).is_dir():
        write_metadata(Path(bag), meta)
    return meta


def _rewrite(src: Path) -> None:
    """Copy the complete messages of an unfinished file into a finished one in its place."""
    writer_mod = _mcap()
    from mcap.records import Channel, Schema
    from mcap.stream_reader import StreamReader
    defs: Dict[str, bytes] = {}
    chan_meta: Dict[str, dict] = {}
    with open(src, 'rb') as f:
        try:
            for rec in StreamReader(f, record_size_limit=None).records:
                if isinstance(rec, Schema):
                    defs[rec.name] = rec.data
                elif isinstance(rec, Channel):
                    chan_meta[rec.topic] = dict(rec.metadata)
        except Exception:  # noqa: BLE001 - truncated: what was read is enough
            pass
    tmp = src.with_suffix('.mcap.repair')
    info = new_file_info(src.name)
    with open(tmp, 'wb') as out:
        w = writer_mod.Writer(out, compression=writer_mod.CompressionType.NONE)
        w.start(profile='ros2', library='sm_ros repair')
        sids: Dict[str, int] = {}
        cids: Dict[str, int] = {}
        for topic, schema, stamp, data, pub in _iter_file(src, None, True):
            if topic not in cids:
                if schema not in sids:
                    sids[schema] = w.register_schema(schema, 'ros2msg',
                                                     defs.get(schema, b''))
                cids[topic] = w.register_channel(topic, 'cdr', sids[schema],
                                                 metadata=chan_meta.get(topic, {}))
            w.add_message(cids[topic], log_time=stamp, data=data, publish_time=pub,
                          sequence=info['counts'].get(topic, 0))
            add_message(info, topic, schema, stamp)
        import yaml
        w.add_metadata('rosbag2', {'serialized_metadata': yaml.safe_dump(
            metadata_dict([info])['rosbag2_bagfile_information'], default_flow_style=False,
            sort_keys=False)})
        w.finish()
    os.replace(tmp, src)


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m sm_ros.record info|repair BAG``."""
    ap = argparse.ArgumentParser(prog='python -m sm_ros.record', description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('command', choices=('info', 'repair'))
    ap.add_argument('bag', help='rosbag2 folder (or .mcap file)')
    args = ap.parse_args(argv)
    try:
        if args.command == 'repair':
            meta = repair(args.bag)['rosbag2_bagfile_information']
            print(f"{args.bag}: repaired, {meta['message_count']} messages")
            return 0
        counts: Dict[str, int] = {}
        types: Dict[str, str] = {}
        first, last = None, 0
        for topic, schema, stamp, _ in iter_raw(args.bag):
            counts[topic] = counts.get(topic, 0) + 1
            types[topic] = schema
            first = stamp if first is None else min(first, stamp)
            last = max(last, stamp)
    except (FileNotFoundError, RecordUnavailable) as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    span = (last - first) * 1e-9 if first is not None else 0.0
    print(f'{args.bag}: {sum(counts.values())} messages over {span:.3f} s')
    for topic in sorted(counts):
        print(f'  {topic:<24} {types[topic]:<36} {counts[topic]}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
