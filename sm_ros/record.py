"""
Recordings that ROS tools replay: a rosbag2 folder with MCAP storage.

``BagRecorder(path)`` creates ``path/`` holding ``metadata.yaml`` and ``<name>_0.mcap``
(the layout ``ros2 bag record -s mcap`` writes), with ROS 2 CDR messages and ``ros2msg``
schemas, written with the MCAP library for Python (``pip install '.[record]'``). So
``ros2 bag info``/``ros2 bag play``, Foxglove and ``rosbags`` open it.

Ticks never wait for the disk: ``write(topic, type, data, stamp_ns)`` puts the already
serialised message on a bounded queue (by count and by bytes) and returns; a background
thread writes. When the queue is full the message is dropped and counted (``dropped``,
reported by the node's diagnostics as ``recorder_dropped``).

A run that stops at any moment leaves a file that can be read:

- stopping (service, parameter, Ctrl-C, SIGTERM, the end of the process) closes the
  writer: last chunk, summary, footer and ``metadata.yaml`` with the final counts;
- at least every ``flush_s`` seconds the open chunk is closed and flushed to the file and
  ``metadata.yaml`` is rewritten (atomically) with the counts so far, so a process that is
  killed (SIGKILL, power loss) leaves every message of the closed chunks in a file that
  MCAP's streaming reader reads to its end; ``python -m sm_ros.record repair BAG`` (like
  ``ros2 bag reindex``) rewrites it with its summary so that indexed readers open it too.

The module is ROS-free: message definitions are read from the ``.msg`` files of the
installed interface packages (``<prefix>/share/<package>/msg``).

Command line::

    python -m sm_ros.record info BAG      # topics, counts, time span (needs rosbags or mcap)
    python -m sm_ros.record repair BAG    # after a crash: rewrite summary and metadata
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

#: Message definition separator of ROS 2 ``ros2msg`` schemas (as rosbag2 writes them).
_SEPARATOR = '=' * 80
_PRIMITIVES = {
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring',
}
#: The QoS rosbag2 replays with (reliable, volatile, keep last 10), in the version 8 form.
_INFINITE = {'sec': 9223372036, 'nsec': 854775807}
_QOS_V8 = [{
    'history': 1, 'depth': 10, 'reliability': 1, 'durability': 2,
    'deadline': dict(_INFINITE), 'lifespan': dict(_INFINITE), 'liveliness': 1,
    'liveliness_lease_duration': dict(_INFINITE), 'avoid_ros_namespace_conventions': False,
}]


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
# Message definitions from the installed .msg files
# ----------------------------------------------------------------------------------------

def _share_dirs() -> List[Path]:
    dirs = []
    for prefix in [sys.prefix] + os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix:
            p = Path(prefix) / 'share'
            if p.is_dir() and p not in dirs:
                dirs.append(p)
    return dirs


def msg_file(msgtype: str) -> Path:
    """Return the ``.msg`` file of ``pkg/msg/Type`` (or ``pkg/Type``)."""
    pkg, _, name = _normalize(msgtype).partition('/msg/')
    for share in _share_dirs():
        path = share / pkg / 'msg' / f'{name}.msg'
        if path.is_file():
            return path
    raise FileNotFoundError(f'no {pkg}/msg/{name}.msg under '
                            f"{', '.join(str(d) for d in _share_dirs()) or 'any prefix'}")


def _normalize(msgtype: str) -> str:
    parts = msgtype.split('/')
    if len(parts) == 2:
        return f'{parts[0]}/msg/{parts[1]}'
    if len(parts) == 3:
        return msgtype
    raise ValueError(f"message type must be 'pkg/msg/Type', got '{msgtype}'")


def _field_types(text: str, pkg: str) -> List[str]:
    """Return the non-primitive types used by the fields of a .msg text."""
    out = []
    for line in text.splitlines():
        line = line.split('#', 1)[0].strip()
        if not line:
            continue
        typ = line.split()[0]   # constants and defaults only follow primitive types
        base = re.sub(r'\[.*\]$', '', typ)
        base = re.sub(r'<=\d+$', '', base)
        if base in _PRIMITIVES:
            continue
        if '/' not in base:
            base = 'std_msgs/Header' if base == 'Header' else f'{pkg}/{base}'
        out.append(_normalize(base))
    return out


def message_definition(msgtype: str) -> str:
    """
    Return the ``ros2msg`` schema text of ``msgtype``: its .msg text, then every type it
    uses (depth first, each once) after a separator line and ``MSG: pkg/Type``.
    """
    main = _normalize(msgtype)
    seen: Dict[str, str] = {}
    order: List[str] = []

    def visit(t: str) -> None:
        if t in seen:
            return
        text = msg_file(t).read_text(encoding='utf-8')
        seen[t] = text
        if t != main:
            order.append(t)
        for dep in _field_types(text, t.split('/')[0]):
            visit(dep)

    visit(main)
    parts = [seen[main].rstrip('\n')]
    for t in order:
        pkg, _, name = t.partition('/msg/')
        parts.append(f'{_SEPARATOR}\nMSG: {pkg}/{name}\n{seen[t].rstrip(chr(10))}')
    return '\n'.join(parts) + '\n'


# ----------------------------------------------------------------------------------------
# metadata.yaml
# ----------------------------------------------------------------------------------------

def metadata_dict(mcap_name: str, topics: Dict[str, str], counts: Dict[str, int],
                  start_ns: int, end_ns: int) -> dict:
    """Return rosbag2's ``metadata.yaml`` content (version 8) as a dict."""
    import yaml
    qos = yaml.safe_dump(_QOS_V8, default_flow_style=False).strip()
    total = sum(counts.values())
    start = start_ns if total else 0
    duration = max(0, end_ns - start_ns) if total else 0
    return {'rosbag2_bagfile_information': {
        'version': 8,
        'storage_identifier': 'mcap',
        'relative_file_paths': [mcap_name],
        'duration': {'nanoseconds': int(duration)},
        'starting_time': {'nanoseconds_since_epoch': int(start)},
        'message_count': int(total),
        'topics_with_message_count': [
            {'topic_metadata': {'name': name, 'type': typ, 'serialization_format': 'cdr',
                                'offered_qos_profiles': qos, 'type_description_hash': ''},
             'message_count': int(counts.get(name, 0))}
            for name, typ in topics.items()],
        'compression_format': '',
        'compression_mode': '',
        'files': [{'path': mcap_name,
                   'starting_time': {'nanoseconds_since_epoch': int(start)},
                   'duration': {'nanoseconds': int(duration)},
                   'message_count': int(total)}],
        'custom_data': {'writer': 'sm_ros'},
        'ros_distro': 'jazzy',
    }}


def _write_metadata(folder: Path, meta: dict) -> None:
    import yaml
    tmp = folder / 'metadata.yaml.tmp'
    tmp.write_text(yaml.safe_dump(meta, default_flow_style=False, sort_keys=False))
    os.replace(tmp, folder / 'metadata.yaml')


# ----------------------------------------------------------------------------------------
# The recorder
# ----------------------------------------------------------------------------------------

class BagRecorder:
    """
    Record serialised ROS 2 messages into a rosbag2 (MCAP) folder on a background thread.

    ``path`` must not exist yet (like ``ros2 bag record -o``). ``max_queue`` and
    ``max_queue_bytes`` bound what waits for the disk; ``chunk_bytes`` is the MCAP chunk
    size; ``compression`` is '' (none: no CPU taken from the solver) or 'zstd'.
    """

    def __init__(self, path, max_queue: int = 256, max_queue_bytes: int = 512 << 20,
                 chunk_bytes: int = 4 << 20, flush_s: float = 1.0, compression: str = ''):
        """Create the folder, open the MCAP file and start the writer thread."""
        writer_mod = _mcap()
        self.path = Path(path)
        if self.path.exists():
            raise FileExistsError(f'{self.path} exists already (recordings are never '
                                  'overwritten)')
        if compression not in ('', 'zstd', 'lz4'):
            raise ValueError(f"compression must be '', 'zstd' or 'lz4', got '{compression}'")
        self.path.mkdir(parents=True)
        self.mcap_name = f'{self.path.name}_0.mcap'
        self._file = open(self.path / self.mcap_name, 'wb')
        comp = {'': writer_mod.CompressionType.NONE, 'zstd': writer_mod.CompressionType.ZSTD,
                'lz4': writer_mod.CompressionType.LZ4}[compression]
        self._writer = writer_mod.Writer(self._file, chunk_size=int(chunk_bytes),
                                         compression=comp)
        self._writer.start(profile='ros2', library='sm_ros')
        self.topics: Dict[str, str] = {}
        self.counts: Dict[str, int] = {}
        self._channels: Dict[str, int] = {}
        self._schemas: Dict[str, int] = {}
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
        _write_metadata(self.path, metadata_dict(self.mcap_name, {}, {}, 0, 0))
        self._thread = threading.Thread(target=self._run, name='sm_ros-recorder', daemon=True)
        self._thread.start()

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
        self.topics[topic] = _normalize(msgtype)
        self.counts[topic] = 0
        return cid

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
                topic, msgtype, data, stamp, pub = item
                with self._lock:
                    self._queued_bytes -= len(data)
                if self.error is None:
                    try:
                        cid = self._channel(topic, msgtype)
                        seq = self.counts[topic]
                        self._writer.add_message(channel_id=cid, log_time=stamp, data=data,
                                                 publish_time=pub, sequence=seq)
                        self.counts[topic] = seq + 1
                        self.written += 1
                        if self.start_ns is None or stamp < self.start_ns:
                            self.start_ns = stamp
                        self.end_ns = max(self.end_ns, stamp)
                    except Exception as exc:  # noqa: BLE001 - disk full, bad type: stop
                        self.error = f'{type(exc).__name__}: {exc}'
                else:
                    self.dropped += 1
            now = time.monotonic()
            if now - last_flush >= self._flush_s and self.error is None:
                self._flush()
                last_flush = now

    def _metadata(self) -> dict:
        return metadata_dict(self.mcap_name, self.topics, self.counts, self.start_ns or 0,
                             self.end_ns)

    def _flush(self) -> None:
        try:
            self._writer.flush()
            self._file.flush()
            _write_metadata(self.path, self._metadata())
        except Exception as exc:  # noqa: BLE001
            self.error = f'{type(exc).__name__}: {exc}'

    # ------------------------------------------------------------------ stop

    def close(self, timeout: float = 30.0) -> dict:
        """Write what is queued, close the file (summary, footer), write metadata.yaml."""
        if self._closed:
            return self._metadata()
        self._closed = True
        self._queue.put((None, None, None, 0, 0))
        self._thread.join(timeout)
        meta = self._metadata()
        info = meta['rosbag2_bagfile_information']
        try:
            import yaml
            self._writer.add_metadata('rosbag2', {
                'serialized_metadata': yaml.safe_dump(info, default_flow_style=False,
                                                      sort_keys=False)})
            self._writer.finish()
        finally:
            self._file.close()
        _write_metadata(self.path, meta)
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

def mcap_path(bag) -> Path:
    """Return the .mcap file of a bag folder (or the file itself)."""
    p = Path(bag)
    if p.is_file():
        return p
    files = sorted(p.glob('*.mcap'))
    if not files:
        raise FileNotFoundError(f'{p}: no .mcap file (is it a rosbag2 MCAP folder?)')
    return files[0]


def iter_raw(bag, topics: Optional[Sequence[str]] = None, publish_time: bool = False
             ) -> Iterator[Tuple[str, str, int, bytes]]:
    """
    Yield (topic, schema name, log time ns, CDR bytes) in file order (with
    ``publish_time``: (topic, schema name, log time, CDR bytes, publish time)).

    Reads records one after the other (no index needed), so a file that was cut short by
    a crash is read up to its last complete chunk.
    """
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader
    schemas: Dict[int, str] = {}
    channels: Dict[int, Tuple[str, str]] = {}
    with open(mcap_path(bag), 'rb') as f:
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


def repair(bag) -> dict:
    """
    Rewrite a bag whose writer was killed: every complete message is copied into a new,
    indexed MCAP file that replaces the old one, and metadata.yaml gets the true counts.
    Returns the new metadata.
    """
    writer_mod = _mcap()
    folder = Path(bag)
    src = mcap_path(folder)
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
    counts: Dict[str, int] = {}
    topics: Dict[str, str] = {}
    start, end = None, 0
    with open(tmp, 'wb') as out:
        w = writer_mod.Writer(out, compression=writer_mod.CompressionType.NONE)
        w.start(profile='ros2', library='sm_ros repair')
        sids: Dict[str, int] = {}
        cids: Dict[str, int] = {}
        for topic, schema, stamp, data, pub in iter_raw(src, publish_time=True):
            if topic not in cids:
                if schema not in sids:
                    sids[schema] = w.register_schema(schema, 'ros2msg',
                                                     defs.get(schema, b''))
                cids[topic] = w.register_channel(topic, 'cdr', sids[schema],
                                                 metadata=chan_meta.get(topic, {}))
                topics[topic] = schema
                counts[topic] = 0
            w.add_message(cids[topic], log_time=stamp, data=data, publish_time=pub,
                          sequence=counts[topic])
            counts[topic] += 1
            start = stamp if start is None else min(start, stamp)
            end = max(end, stamp)
        meta = metadata_dict(src.name, topics, counts, start or 0, end)
        import yaml
        w.add_metadata('rosbag2', {'serialized_metadata': yaml.safe_dump(
            meta['rosbag2_bagfile_information'], default_flow_style=False, sort_keys=False)})
        w.finish()
    os.replace(tmp, src)
    if folder.is_dir():
        _write_metadata(folder, meta)
    return meta


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
