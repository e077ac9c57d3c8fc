"""
What a rosbag2 folder holds beside the messages: the ``ros2msg`` schemas, read from the
``.msg`` files of the installed interface packages (``<prefix>/share/<package>/msg``), and
``metadata.yaml`` (version 8, the form ``ros2 bag record -s mcap`` writes on Jazzy).

ROS-free; ``sm_ros.record`` writes recordings with them.
"""

from __future__ import annotations

import os
from pathlib import Path
import re
import sys
from typing import Dict, List, Sequence

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

def new_file_info(name: str) -> dict:
    """What metadata.yaml says of one .mcap file: its name, topics (name: type), message
    counts per topic and the first and last log times (ns)."""
    return {'path': name, 'topics': {}, 'counts': {}, 'start': None, 'end': 0}


def add_message(info: dict, topic: str, msgtype: str, stamp_ns: int) -> None:
    """Count one message of ``topic`` logged at ``stamp_ns`` into a file's info."""
    info['topics'].setdefault(topic, msgtype)
    info['counts'][topic] = info['counts'].get(topic, 0) + 1
    info['start'] = stamp_ns if info['start'] is None else min(info['start'], stamp_ns)
    info['end'] = max(info['end'], stamp_ns)


def metadata_dict(files: Sequence[dict], custom: Dict[str, str] = None) -> dict:
    """Return rosbag2's ``metadata.yaml`` content (version 8) as a dict for the .mcap
    ``files`` (:func:`new_file_info`), in order; ``custom`` joins its custom_data."""
    import yaml
    qos = yaml.safe_dump(_QOS_V8, default_flow_style=False).strip()
    topics: Dict[str, str] = {}
    counts: Dict[str, int] = {}
    for info in files:
        for name, typ in info['topics'].items():
            topics.setdefault(name, typ)
            counts[name] = counts.get(name, 0) + info['counts'].get(name, 0)
    starts = [f['start'] for f in files if f['start'] is not None]
    start = min(starts) if starts else 0
    end = max((f['end'] for f in files if f['start'] is not None), default=0)

    def span(first, last):
        return ({'nanoseconds_since_epoch': int(first or 0)},
                {'nanoseconds': int(max(0, last - first)) if first is not None else 0})

    entries = []
    for info in files:
        begin, duration = span(info['start'], info['end'])
        entries.append({'path': info['path'], 'starting_time': begin, 'duration': duration,
                        'message_count': int(sum(info['counts'].values()))})
    begin, duration = span(start if starts else None, end)
    return {'rosbag2_bagfile_information': {
        'version': 8,
        'storage_identifier': 'mcap',
        'relative_file_paths': [f['path'] for f in files],
        'duration': duration,
        'starting_time': begin,
        'message_count': int(sum(counts.values())),
        'topics_with_message_count': [
            {'topic_metadata': {'name': name, 'type': typ, 'serialization_format': 'cdr',
                                'offered_qos_profiles': qos, 'type_description_hash': ''},
             'message_count': int(counts[name])}
            for name, typ in topics.items()],
        'compression_format': '',
        'compression_mode': '',
        'files': entries,
        'custom_data': {'writer': 'sm_ros', **(custom or {})},
        'ros_distro': 'jazzy',
    }}


def write_metadata(folder: Path, meta: dict) -> None:
    """Write ``folder/metadata.yaml`` whole (a temporary file, then renamed)."""
    import yaml
    tmp = folder / 'metadata.yaml.tmp'
    tmp.write_text(yaml.safe_dump(meta, default_flow_style=False, sort_keys=False))
    os.replace(tmp, folder / 'metadata.yaml')
