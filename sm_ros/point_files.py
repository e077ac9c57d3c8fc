"""
Point-cloud files for scene bodies: PLY, PCD (with LZF) and .npy, read with NumPy alone.

The readers are written here (no extra dependency) and return (N, 3) float64 arrays; they
raise :class:`sm_ros.shapes.GeometryError` with a short reason (the scene loader adds the
file, body and key) that names a line or a row, never the file's text.
``read_cloud_file`` picks the reader by the file's extension.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .shapes import GeometryError

_PLY_TYPES = {
    'char': 'i1', 'int8': 'i1', 'uchar': 'u1', 'uint8': 'u1', 'short': 'i2', 'int16': 'i2',
    'ushort': 'u2', 'uint16': 'u2', 'int': 'i4', 'int32': 'i4', 'uint': 'u4', 'uint32': 'u4',
    'float': 'f4', 'float32': 'f4', 'double': 'f8', 'float64': 'f8',
}


def read_ply_points(path: Path) -> np.ndarray:
    """
    Vertex positions (N, 3) of a PLY file (ascii, binary_little_endian, binary_big_endian).

    Reads the ``vertex`` element's x, y, z; other elements (faces) are ignored as long as
    the vertex element comes first or the elements before it have no list properties.
    """
    data = Path(path).read_bytes()
    end = data.find(b'end_header')
    if not data.startswith(b'ply') or end < 0:
        raise GeometryError('not a PLY file (no "ply" magic or no end_header)')
    nl = data.find(b'\n', end)
    body = data[nl + 1:] if nl >= 0 else b''
    fmt = None
    elements = []  # [name, count, [(prop, type or None for list)]]
    for number, line in enumerate(data[:end].decode('ascii', errors='replace').splitlines()):
        tok = line.split()
        if not tok:
            continue
        if tok[0] == 'format':
            fmt = tok[1] if len(tok) > 1 else None
        elif tok[0] == 'element' and len(tok) == 3:
            if not tok[2].isdigit():
                raise GeometryError(f'PLY header line {number + 1}: element count is not '
                                    'a number')
            elements.append([tok[1], int(tok[2]), []])
        elif tok[0] == 'property' and elements:
            if tok[1] == 'list':
                elements[-1][2].append((tok[-1], None))
            elif len(tok) == 3 and tok[1] in _PLY_TYPES:
                elements[-1][2].append((tok[2], _PLY_TYPES[tok[1]]))
            else:
                raise GeometryError(f'PLY header line {number + 1}: unsupported property')
    if fmt not in ('ascii', 'binary_little_endian', 'binary_big_endian'):
        raise GeometryError('unsupported PLY format (not ascii, binary_little_endian or '
                            'binary_big_endian)')
    names = [e[0] for e in elements]
    if 'vertex' not in names:
        raise GeometryError('PLY file has no vertex element')
    vi = names.index('vertex')
    vprops = elements[vi][2]
    pnames = [p for p, _ in vprops]
    if not all(c in pnames for c in 'xyz'):
        raise GeometryError('PLY vertex element lacks x, y or z')
    if any(t is None for _, t in vprops):
        raise GeometryError('PLY vertex element has list properties')
    count = elements[vi][1]
    if fmt == 'ascii':
        lines = body.decode('ascii', errors='replace').splitlines()
        skip = sum(e[1] for e in elements[:vi])
        rows = [ln.split() for ln in lines[skip:skip + count]]
        if len(rows) < count or any(len(r) < len(pnames) for r in rows):
            raise GeometryError('PLY ascii data is shorter than its header says')
        return _ascii_xyz(rows, [pnames.index(c) for c in 'xyz'], 'PLY vertex')
    endian = '<' if fmt == 'binary_little_endian' else '>'
    offset = 0
    for e in elements[:vi]:
        if any(t is None for _, t in e[2]):
            raise GeometryError('a PLY element before vertex has list properties')
        offset += e[1] * sum(np.dtype(t).itemsize for _, t in e[2])
    dt = np.dtype([(p, endian + t) for p, t in vprops])
    if len(body) < offset + count * dt.itemsize:
        raise GeometryError('PLY binary data is shorter than its header says')
    rec = np.frombuffer(body, dtype=dt, count=count, offset=offset)
    return np.stack([rec[c].astype(np.float64) for c in 'xyz'], axis=1)


def _ascii_xyz(rows, columns, what: str) -> np.ndarray:
    """The (N, 3) floats in ``columns`` of split ascii ``rows``; an error names the row."""
    out = np.empty((len(rows), 3))
    for i, row in enumerate(rows):
        try:
            out[i] = [float(row[c]) for c in columns]
        except ValueError:
            raise GeometryError(f'{what} {i + 1} is not numeric') from None
    return out


def lzf_decompress(data: bytes, out_len: int) -> bytes:
    """Decompress LZF data (the codec of PCD ``binary_compressed``)."""
    out = bytearray(out_len)
    ip = op = 0
    n = len(data)
    try:
        while ip < n:
            ctrl = data[ip]
            ip += 1
            if ctrl < 32:                       # literal run of ctrl + 1 bytes
                ln = ctrl + 1
                if op + ln > out_len or ip + ln > n:
                    raise GeometryError('corrupt LZF data (literal overruns)')
                out[op:op + ln] = data[ip:ip + ln]
                ip += ln
                op += ln
            else:                               # back reference
                ln = ctrl >> 5
                if ln == 7:
                    ln += data[ip]
                    ip += 1
                ref = op - ((ctrl & 0x1F) << 8) - data[ip] - 1
                ip += 1
                ln += 2
                if ref < 0 or op + ln > out_len:
                    raise GeometryError('corrupt LZF data (bad back reference)')
                if ref + ln <= op:
                    out[op:op + ln] = out[ref:ref + ln]
                    op += ln
                else:
                    for _ in range(ln):         # overlapping copy, byte by byte
                        out[op] = out[ref]
                        op += 1
                        ref += 1
    except IndexError:
        raise GeometryError('corrupt LZF data (truncated)') from None
    if op != out_len:
        raise GeometryError(f'LZF data decompressed to {op} bytes, header says {out_len}')
    return bytes(out)


def read_pcd_points(path: Path) -> np.ndarray:
    """
    Positions (N, 3) of a PCD file (DATA ascii, binary or binary_compressed).

    Fields other than x, y, z are skipped; organised clouds are flattened.
    """
    data = Path(path).read_bytes()
    header = {}
    pos = 0
    while True:
        nl = data.find(b'\n', pos)
        if nl < 0:
            raise GeometryError('PCD header has no DATA line')
        line = data[pos:nl].decode('ascii', errors='replace').strip()
        pos = nl + 1
        if not line or line.startswith('#'):
            continue
        tok = line.split()
        header[tok[0].upper()] = tok[1:]
        if tok[0].upper() == 'DATA':
            break
    try:
        fields = header['FIELDS']
        sizes = [int(s) for s in header['SIZE']]
        types = header['TYPE']
        counts = [int(c) for c in header.get('COUNT', ['1'] * len(fields))]
        npts = int(header['POINTS'][0]) if 'POINTS' in header else (
            int(header['WIDTH'][0]) * int(header.get('HEIGHT', ['1'])[0]))
        mode = header['DATA'][0].lower()
    except KeyError as exc:
        raise GeometryError(f'PCD header has no {exc.args[0]} line') from None
    except (IndexError, ValueError):
        raise GeometryError('PCD header is malformed (a count that is no number, or an '
                            'empty line)') from None
    if not (len(fields) == len(sizes) == len(types) == len(counts)):
        raise GeometryError('PCD FIELDS, SIZE, TYPE and COUNT differ in length')
    if not all(c in fields for c in 'xyz'):
        raise GeometryError('PCD file lacks an x, y or z field')
    kinds = {'F': 'f', 'I': 'i', 'U': 'u'}
    try:
        dts = [np.dtype(f'<{kinds[t.upper()]}{s}') for t, s in zip(types, sizes)]
    except (KeyError, TypeError):
        raise GeometryError('PCD has an unsupported TYPE/SIZE (F 4/8, I or U 1/2/4/8)') \
            from None
    body = data[pos:]
    if mode == 'ascii':
        cols = []
        for f, c in zip(fields, counts):
            cols.extend([f] * c)
        rows = body.decode('ascii', errors='replace').split('\n')
        rows = [r.split() for r in rows if r.strip()][:npts]
        if len(rows) < npts or any(len(r) < len(cols) for r in rows):
            raise GeometryError('PCD ascii data is shorter than its header says')
        return _ascii_xyz(rows, [cols.index(c) for c in 'xyz'], 'PCD point')
    if mode == 'binary':
        dt = np.dtype([(f, d, (c,)) if c > 1 else (f, d)
                       for f, d, c in zip(fields, dts, counts)])
        if len(body) < npts * dt.itemsize:
            raise GeometryError('PCD binary data is shorter than its header says')
        rec = np.frombuffer(body, dtype=dt, count=npts)
        return np.stack([rec[c].astype(np.float64).reshape(npts) for c in 'xyz'], axis=1)
    if mode == 'binary_compressed':
        if len(body) < 8:
            raise GeometryError('PCD binary_compressed data is truncated')
        csize, usize = np.frombuffer(body[:8], dtype='<u4')
        raw = lzf_decompress(body[8:8 + int(csize)], int(usize))
        # column-major: all values of field 0, then field 1, ...
        off = 0
        cols = {}
        for f, d, c in zip(fields, dts, counts):
            nbytes = npts * c * d.itemsize
            if off + nbytes > len(raw):
                raise GeometryError('PCD binary_compressed data is shorter than its header')
            cols[f] = np.frombuffer(raw, dtype=d, count=npts * c, offset=off)
            off += nbytes
        return np.stack([cols[c].astype(np.float64)[:npts] for c in 'xyz'], axis=1)
    raise GeometryError('unsupported PCD DATA mode (not ascii, binary or binary_compressed)')


def read_npy_points(path: Path) -> np.ndarray:
    """Positions (N, 3) from a .npy array: shape (N, >= 3) (first three columns) or a
    structured array with x, y, z fields."""
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        # NumPy's message quotes the file's header: only its kind is reported
        raise GeometryError(f'cannot read .npy ({type(exc).__name__})') from None
    if arr.dtype.names:
        if not all(c in arr.dtype.names for c in 'xyz'):
            raise GeometryError('structured .npy lacks an x, y or z field')
        return np.stack([arr[c].astype(np.float64).reshape(-1) for c in 'xyz'], axis=1)
    if arr.ndim != 2 or arr.shape[1] < 3 or not np.issubdtype(arr.dtype, np.number):
        raise GeometryError(f'.npy must be a numeric (N, 3) array, got shape {arr.shape} '
                            f'of {arr.dtype}')
    return arr[:, :3].astype(np.float64)


def read_cloud_file(path: Path) -> np.ndarray:
    """Read a point-cloud file by extension (.ply, .pcd, .npy); non-finite rows dropped."""
    ext = Path(path).suffix.lower()
    readers = {'.ply': read_ply_points, '.pcd': read_pcd_points, '.npy': read_npy_points}
    if ext not in readers:
        raise GeometryError(f'unsupported cloud file type {ext!r} (use .ply, .pcd or .npy)')
    pts = readers[ext](path)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) == 0:
        raise GeometryError('the cloud file has no finite point')
    return pts
