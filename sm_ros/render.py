"""
Run a scene headless and draw it: an animated GIF or a PNG strip of frames (no display).

Usage::

    python -m sm_ros.render SCENE [--seconds 3] [--out run.gif] [--fps 10] [--dt 0.008333]
                            [--set mode=quadratic --set alpha=0.3 ...]

SCENE is a bundled scene name or a YAML path, or a recording (a rosbag2 MCAP folder made
by the node's ``~/record`` service or ``ros2 bag record``, or its ``.mcap`` file): then the
recorded ``points`` clouds are drawn (``--seconds`` from the start of the recording, frames
picked every 1/``--fps`` s of the clouds' simulation time (MCAP publish time); ``--topic``
picks the cloud topic, default: the first PointCloud2 topic) and nothing is simulated. The
output type follows the extension of ``--out``: ``.gif`` (animated, via Pillow) or ``.png``
(``--frames`` panels side by side).
The simulation uses the node's defaults (``sm_ros.params.scene_defaults()``, ``--dt`` like the
node's ``dt``); ``--set key=value`` changes a node parameter for the run. Drawing uses
matplotlib's Agg backend, so it runs without a display.
"""

from __future__ import annotations

import argparse
import io
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence

import numpy as np

from sm_ros.params import scene_defaults
from sm_ros.scene import build_world, load_scene, SceneError

#: Default step, like the node's ``dt`` parameter (s).
DEFAULT_DT = 1.0 / 120.0

_COLOURS = ['#1f77b4', '#ff7f0e', '#2ca02c', '#d62728', '#9467bd', '#8c564b', '#e377c2',
            '#7f7f7f', '#bcbd22', '#17becf']


@dataclass
class Recording:
    """Positions of every body at each frame, plus what is needed to draw them."""

    name: str
    times: List[float]
    frames: List[List[np.ndarray]]        # frame -> body -> (n_drawn, 3)
    surfaces: List[List[Optional[np.ndarray]]]   # frame -> body -> (V, 3) or None
    faces: List[Optional[np.ndarray]]
    colliders: Dict[str, Any]
    ground: Optional[float]
    n_points: int
    step_ms: float
    #: frame -> [(kind, centre (3,), rotation (3, 3), dims (3,))] of the colliders of the
    #: collider pass (named, oriented, kinematic, capsules), drawn where they are
    solids: List[list] = field(default_factory=list)


def _parse_value(text: str) -> Any:
    import yaml
    return yaml.safe_load(text)


def simulate(scene: str, seconds: float = 3.0, fps: float = 10.0, dt: float = DEFAULT_DT,
             params: Optional[Dict[str, Any]] = None, max_draw: int = 4000,
             seed: int = 0) -> Recording:
    """
    Load `scene`, step it for `seconds` of simulated time with step `dt`, and record a frame
    every 1/`fps` s. At most `max_draw` particles (a fixed random subset, shared fairly
    among the bodies) are recorded for drawing; mesh surfaces are recorded whole.
    """
    defaults = scene_defaults()
    defaults.update(params or {})
    spec = load_scene(scene)
    world, metas = build_world(spec, defaults)
    rng = np.random.default_rng(seed)
    total = max(1, spec.n_points)
    picks = []
    for body in world.bodies:
        drawn = max(1, int(round(max_draw * body.n / total))) if total > max_draw else body.n
        picks.append(np.sort(rng.choice(body.n, size=min(drawn, body.n), replace=False)))
    per_frame = max(1, int(round(1.0 / (fps * dt))))
    n_frames = int(round(seconds * fps)) + 1
    rec = Recording(name=Path(str(scene)).stem or 'default', times=[], frames=[], surfaces=[],
                    faces=[meta.surface.faces if meta.surface is not None else None
                           for meta in metas],
                    colliders=spec.colliders, ground=None, n_points=spec.n_points,
                    step_ms=0.0)
    if world.ground is not None:
        rec.ground = float(world.ground.height)
    steps = 0
    busy = 0.0
    from sm_ros.progress import bar
    for frame in bar(iterable=range(n_frames), total=n_frames, desc='simulate', unit='frame'):
        if frame:
            t0 = time.perf_counter()
            for _ in range(per_frame):
                world.step(dt)
            busy += time.perf_counter() - t0
            steps += per_frame
        rec.times.append(world.time)
        rec.frames.append([body.x[pick].copy() for body, pick in zip(world.bodies, picks)])
        rec.surfaces.append([meta.surface.vertices(body.x).copy()
                             if meta.surface is not None else None
                             for body, meta in zip(world.bodies, metas)])
        rec.solids.append(_solids(world))
    rec.step_ms = 1000.0 * busy / max(1, steps)
    return rec


def _solids(world) -> list:
    """Return the current (kind, centre, rotation, dims) of the collider pass's colliders."""
    colliders = getattr(world, '_cset', None)
    if colliders is None:
        return []
    from sm_ros.core import kinematic as KC
    return [(int(row[KC.C_KIND]), row[KC.C_POS:KC.C_POS + 3].copy(),
             row[KC.C_ROT:KC.C_ROT + 9].reshape(3, 3).copy(), row[KC.C_DIM:KC.C_DIM + 3].copy())
            for row in colliders.rows]


def _draw_solids(ax, solids, lo, hi) -> None:
    """Draw oriented boxes, spheres and capsules (kinematic.py rows) where they are."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 20), np.linspace(0, np.pi, 11))
    for kind, c, rot, dims in solids:
        if kind == 1:
            h = dims
            corners = np.array([[x, y, z] for x in (-h[0], h[0]) for y in (-h[1], h[1])
                                for z in (-h[2], h[2])]) @ rot.T + c
            quads = [corners[[0, 1, 3, 2]], corners[[4, 5, 7, 6]], corners[[0, 1, 5, 4]],
                     corners[[2, 3, 7, 6]], corners[[0, 2, 6, 4]], corners[[1, 3, 7, 5]]]
            ax.add_collection3d(Poly3DCollection(quads, facecolor='#8c8c8c',
                                                 edgecolor='#606060', alpha=0.4, zorder=1))
            continue
        r = dims[0]
        half = dims[1] if kind == 2 else 0.0
        # a sphere stretched along local z by the capsule's half length: the two caps and
        # the cylinder between them in one surface
        x, y, z = r * np.cos(u) * np.sin(v), r * np.sin(u) * np.sin(v), r * np.cos(v)
        z = z + np.where(z >= 0.0, half, -half)
        pts = np.stack([x, y, z], axis=-1) @ rot.T + c
        ax.plot_surface(pts[..., 0], pts[..., 1], np.maximum(pts[..., 2], lo[2]),
                        color='#8c8c8c', alpha=0.45, linewidth=0, shade=True, zorder=1)


def is_recording(path: str) -> bool:
    """Return True if ``path`` is a rosbag2 folder with an .mcap file, or an .mcap file."""
    candidate = Path(str(path))
    return (candidate.is_file() and candidate.suffix == '.mcap') or \
        (candidate.is_dir() and any(candidate.glob('*.mcap')))


def _cloud_columns(msg) -> np.ndarray:
    """Return a structured view (x, y, z[, body]) over a decoded PointCloud2's data."""
    kinds = {1: 'i1', 2: 'u1', 3: 'i2', 4: 'u2', 5: 'i4', 6: 'u4', 7: 'f4', 8: 'f8'}
    order = '>' if msg.is_bigendian else '<'
    names, formats, offsets = [], [], []
    for cloud_field in msg.fields:
        if cloud_field.name in ('x', 'y', 'z', 'body') and cloud_field.datatype in kinds:
            names.append(cloud_field.name)
            formats.append(order + kinds[cloud_field.datatype])
            offsets.append(cloud_field.offset)
    dtype = np.dtype({'names': names, 'formats': formats, 'offsets': offsets,
                      'itemsize': msg.point_step})
    return np.frombuffer(bytes(msg.data), dtype=dtype, count=msg.width * msg.height)


def _cloud_records(bag: str, seconds: Optional[float], fps: float, topic: Optional[str]):
    """Return ([(publish time, schema, CDR bytes)] of the clouds on ``topic`` (default: the
    first cloud topic) at ``fps`` for ``seconds``, the topic), file after file."""
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader
    from sm_ros.record import mcap_paths
    frames_raw = []
    t0 = None
    period = 1e9 / fps
    next_t = None
    for path in mcap_paths(bag):            # a recording split into files, in order
        schemas, channels = {}, {}          # ids are per file
        with open(path, 'rb') as stream:
            try:
                for rec in StreamReader(stream, record_size_limit=None).records:
                    if isinstance(rec, Schema):
                        schemas[rec.id] = rec
                    elif isinstance(rec, Channel):
                        channels[rec.id] = rec
                    elif isinstance(rec, Message):
                        channel = channels[rec.channel_id]
                        schema = schemas.get(channel.schema_id)
                        if schema is None or schema.name not in ('sensor_msgs/msg/PointCloud2',
                                                                 'sensor_msgs/PointCloud2'):
                            continue
                        if topic is None:
                            topic = channel.topic
                        if channel.topic != topic:
                            continue
                        t = rec.publish_time     # the simulation time the node stamped
                        if t0 is None:
                            t0 = next_t = t
                        if seconds is not None and t - t0 > seconds * 1e9 + 1:
                            return frames_raw, topic
                        if t + 1 >= next_t:
                            frames_raw.append((t, schema, rec.data))
                            next_t += period * max(1, int((t - next_t) // period) + 1)
            except Exception:  # noqa: BLE001 - a file cut short: keep what was read
                pass
    return frames_raw, topic


def load_recording(bag: str, seconds: Optional[float] = None, fps: float = 10.0,
                   max_draw: int = 4000, topic: Optional[str] = None,
                   seed: int = 0) -> Recording:
    """
    Read the point clouds of a recording into a Recording (no simulation, no ROS).

    Decoding uses the message definitions stored in the file (``mcap_ros2``); a recording
    cut short by a crash is read up to its last complete chunk.
    """
    from mcap_ros2.decoder import DecoderFactory
    factory = DecoderFactory()
    frames_raw, topic = _cloud_records(bag, seconds, fps, topic)
    if not frames_raw:
        raise ValueError(f'{bag}: no PointCloud2 messages'
                         + (f" on '{topic}'" if topic else ''))
    rng = np.random.default_rng(seed)
    out = Recording(name=Path(str(bag)).stem, times=[], frames=[], surfaces=[], faces=[],
                    colliders={}, ground=None, n_points=0, step_ms=0.0)
    picks_key, picks = None, []
    for stamp, schema, data in frames_raw:
        msg = factory.decoder_for('cdr', schema)(data)
        cols = _cloud_columns(msg)
        xyz = np.stack([cols['x'], cols['y'], cols['z']], axis=1).astype(np.float64)
        body = cols['body'] if 'body' in cols.dtype.names else np.zeros(len(cols), np.uint32)
        counts = tuple(np.bincount(body).tolist()) if len(body) else ()
        if counts != picks_key:
            total = max(1, len(body))
            picks = []
            for index, count in enumerate(counts):
                idx = np.flatnonzero(body == index)
                drawn = max(1, int(round(max_draw * count / total))) if total > max_draw \
                    else count
                picks.append(np.sort(rng.choice(idx, size=min(drawn, count), replace=False))
                             if count else idx)
            picks_key = counts
        out.times.append((stamp - frames_raw[0][0]) * 1e-9)
        out.frames.append([xyz[pick] for pick in picks])
        out.surfaces.append([None] * len(picks))
        out.n_points = max(out.n_points, len(body))
    out.faces = [None] * max(len(frame) for frame in out.frames)
    # every frame lists every body (a body that appeared later is empty before)
    for frame, surfaces in zip(out.frames, out.surfaces):
        while len(frame) < len(out.faces):
            frame.append(np.zeros((0, 3)))
            surfaces.append(None)
    return out


def _limits(rec: Recording):
    pts = np.concatenate([np.concatenate(frame, axis=0) for frame in rec.frames], axis=0)
    lo = np.percentile(pts, 0.5, axis=0)
    hi = np.percentile(pts, 99.5, axis=0)
    for sphere in rec.colliders.get('spheres', []):
        c, r = np.asarray(sphere['center']), sphere['radius']
        lo, hi = np.minimum(lo, np.maximum(c - r, lo - 0.5)), np.maximum(hi, np.minimum(
            c + r, hi + 0.5))
    for solids in rec.solids:
        for kind, c, _, dims in solids:
            reach = float(np.linalg.norm(dims)) if kind == 1 else dims[0] + (
                dims[1] if kind == 2 else 0.0)
            lo = np.minimum(lo, np.maximum(c - reach, lo - 0.5))
            hi = np.maximum(hi, np.minimum(c + reach, hi + 0.5))
    if rec.ground is not None:
        lo[2] = min(lo[2], rec.ground)
    centre = (lo + hi) / 2.0
    half = np.maximum((hi - lo) / 2.0 * 1.08, 0.05)
    half[:2] = max(half[0], half[1])
    return centre - half, centre + half


def _in_pass(c) -> bool:
    """Whether a scene collider goes through the collider pass (drawn from its pose)."""
    return c.get('name') is not None or c.get('orientation') is not None \
        or bool(c.get('kinematic'))


def _draw(ax, rec: Recording, i: int, lo: np.ndarray, hi: np.ndarray, title: bool = True):
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    ax.cla()
    ax.computed_zorder = False     # colliders first, bodies on top
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(hi - lo)
    ax.set_axis_off()
    if rec.ground is not None:
        z = rec.ground
        quad = [[(lo[0], lo[1], z), (hi[0], lo[1], z), (hi[0], hi[1], z), (lo[0], hi[1], z)]]
        ax.add_collection3d(Poly3DCollection(quad, facecolor='#d9d9d9', edgecolor='#b0b0b0',
                                             alpha=0.6, zorder=0))
    if rec.solids:
        _draw_solids(ax, rec.solids[i], lo, hi)
    for box in rec.colliders.get('boxes', []):
        if _in_pass(box):
            continue
        box_lo, box_hi = np.maximum(box['lo'], lo), np.minimum(box['hi'], hi)
        if np.any(box_hi <= box_lo):
            continue
        c = np.array([[x, y, z] for x in (box_lo[0], box_hi[0]) for y in (box_lo[1], box_hi[1])
                      for z in (box_lo[2], box_hi[2])])
        quads = [c[[0, 1, 3, 2]], c[[4, 5, 7, 6]], c[[0, 1, 5, 4]], c[[2, 3, 7, 6]],
                 c[[0, 2, 6, 4]], c[[1, 3, 7, 5]]]
        ax.add_collection3d(Poly3DCollection(quads, facecolor='#9e9e9e', edgecolor='#707070',
                                             alpha=0.35, zorder=1))
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 24), np.linspace(0, np.pi, 12))
    for sphere in rec.colliders.get('spheres', []):
        if _in_pass(sphere):
            continue
        c, r = np.asarray(sphere['center']), sphere['radius']
        ax.plot_surface(c[0] + r * np.cos(u) * np.sin(v), c[1] + r * np.sin(u) * np.sin(v),
                        np.maximum(c[2] + r * np.cos(v), lo[2]), color='#9e9e9e', alpha=0.35,
                        linewidth=0, shade=True, zorder=1)
    size = float(np.clip(6000.0 / max(1, sum(len(pts) for pts in rec.frames[i])), 0.4, 12.0))
    for j, pts in enumerate(rec.frames[i]):
        colour = _COLOURS[j % len(_COLOURS)]
        surf = rec.surfaces[i][j]
        if surf is not None:
            tris = surf[rec.faces[j]]
            ax.add_collection3d(Poly3DCollection(tris, facecolor=colour, edgecolor='#303030',
                                                 linewidths=0.15, alpha=0.85, zorder=2))
            continue
        ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=size, c=colour, depthshade=True,
                   linewidths=0, zorder=2)
    if title:
        ax.set_title(f'{rec.name}   t = {rec.times[i]:.2f} s', fontsize=9, pad=0)


def write_gif(rec: Recording, out: Path, width: int = 400, height: int = 300,
              colours: int = 48, elev: float = 22.0, azim: float = -60.0) -> None:
    """Write an animated GIF of the recording (Pillow, palette of `colours`)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from PIL import Image
    dpi = 100
    fig = plt.figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    ax = fig.add_axes([0, 0, 1, 0.94], projection='3d')
    ax.view_init(elev=elev, azim=azim)
    lo, hi = _limits(rec)
    images = []
    from sm_ros.progress import bar
    for i in bar(iterable=range(len(rec.frames)), total=len(rec.frames), desc='draw',
                 unit='frame'):
        _draw(ax, rec, i, lo, hi)
        fig.canvas.draw()
        rgb = np.asarray(fig.canvas.buffer_rgba())[..., :3]
        images.append(Image.fromarray(rgb.copy()))
    plt.close(fig)
    palette = images[len(images) // 2].quantize(colors=colours, method=Image.Quantize.MEDIANCUT)
    frames = [image.quantize(palette=palette, dither=Image.Dither.NONE) for image in images]
    duration = int(round(1000.0 * (rec.times[1] - rec.times[0]))) if len(rec.times) > 1 else 100
    frames[0].save(out, save_all=True, append_images=frames[1:], duration=max(20, duration),
                   loop=0, optimize=True, disposal=1)


def write_strip(rec: Recording, out: Path, panels: int = 5, panel_w: int = 240,
                panel_h: int = 220, elev: float = 22.0, azim: float = -60.0) -> None:
    """Write a PNG strip: `panels` frames evenly spaced in time, side by side."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from PIL import Image
    dpi = 100
    idx = np.unique(np.linspace(0, len(rec.frames) - 1, panels).round().astype(int))
    fig = plt.figure(figsize=(panel_w * len(idx) / dpi, panel_h / dpi), dpi=dpi)
    lo, hi = _limits(rec)
    for k, i in enumerate(idx):
        ax = fig.add_axes([k / len(idx), 0, 1 / len(idx), 0.92], projection='3d')
        ax.view_init(elev=elev, azim=azim)
        _draw(ax, rec, int(i), lo, hi, title=False)
        ax.set_title(f't = {rec.times[i]:.2f} s', fontsize=8, pad=0)
    buf = io.BytesIO()
    fig.savefig(buf, format='png', dpi=dpi)
    plt.close(fig)
    img = Image.open(io.BytesIO(buf.getvalue())).convert('RGB')
    img.quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(out, optimize=True)


@dataclass
class View:
    """How a run is drawn: the GIF's size, the PNG strip's panels, the camera, and how many
    particles are drawn at most."""

    width: int = 400
    height: int = 300
    panels: int = 5
    max_draw: int = 4000
    elev: float = 22.0
    azim: float = -60.0


def render(scene: str, out: str, seconds: float = 3.0, fps: float = 10.0,
           dt: float = DEFAULT_DT, params: Optional[Dict[str, Any]] = None,
           view: Optional[View] = None, topic: Optional[str] = None) -> Dict[str, float]:
    """Simulate (or read a recording) and write `out`; return timing figures."""
    view = view or View()
    path = Path(out)
    kind = path.suffix.lower()
    if kind not in ('.gif', '.png'):
        raise ValueError(f'--out must end in .gif or .png, got {out!r}')
    if not (seconds is None or seconds > 0) or not fps > 0 or not dt > 0:
        raise ValueError('seconds, fps and dt must be > 0')
    t0 = time.perf_counter()
    if is_recording(scene):
        rec = load_recording(scene, seconds=seconds, fps=fps, max_draw=view.max_draw,
                             topic=topic)
    else:
        rec = simulate(scene, seconds=seconds, fps=fps, dt=dt, params=params,
                       max_draw=view.max_draw)
    t1 = time.perf_counter()
    if kind == '.gif':
        write_gif(rec, path, width=view.width, height=view.height, elev=view.elev,
                  azim=view.azim)
    else:
        write_strip(rec, path, panels=view.panels, elev=view.elev, azim=view.azim)
    t2 = time.perf_counter()
    return {'points': rec.n_points, 'bodies': len(rec.faces), 'simulate_s': t1 - t0,
            'frames': len(rec.frames),
            'draw_s': t2 - t1, 'step_ms': rec.step_ms, 'bytes': path.stat().st_size}


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Command line entry point (``python -m sm_ros.render``)."""
    parser = argparse.ArgumentParser(prog='python -m sm_ros.render',
                                 description='Run a scene headless and write a GIF or a '
                                             'PNG strip.')
    parser.add_argument('scene', nargs='?', default='',
                    help="bundled scene name, YAML path or recording (rosbag2 MCAP folder "
                         "or .mcap file) (default: 'default')")
    parser.add_argument('--seconds', type=float, default=None,
                    help='simulated seconds (3); of a recording: from its start (all)')
    parser.add_argument('--topic', default=None,
                    help='cloud topic of a recording (default: the first PointCloud2 one)')
    parser.add_argument('--out', default='run.gif', help='output .gif or .png (run.gif)')
    parser.add_argument('--fps', type=float, default=10.0, help='frames per simulated second')
    parser.add_argument('--dt', type=float, default=DEFAULT_DT, help='time step in s (1/120)')
    parser.add_argument('--frames', type=int, default=5, help='panels of a .png strip (5)')
    parser.add_argument('--max-draw', type=int, default=4000, help='particles drawn at most')
    parser.add_argument('--size', default='400x300', help='GIF size WxH in pixels (400x300)')
    parser.add_argument('--elev', type=float, default=22.0, help='view elevation (deg)')
    parser.add_argument('--azim', type=float, default=-60.0, help='view azimuth (deg)')
    parser.add_argument('--set', action='append', default=[], metavar='KEY=VALUE',
                    help='node parameter for the run, e.g. mode=quadratic (repeatable)')
    args = parser.parse_args(argv)
    params: Dict[str, Any] = {}
    for item in args.set:
        key, sep, value = item.partition('=')
        if not sep or key not in scene_defaults():
            parser.error(f'--set {item!r}: expected KEY=VALUE with KEY one of '
                     f"{', '.join(scene_defaults())}")
        params[key] = _parse_value(value)
    try:
        width, height = (int(v) for v in args.size.lower().split('x'))
    except ValueError:
        parser.error(f'--size must be WxH, got {args.size!r}')
    recording = is_recording(args.scene)
    seconds = args.seconds if args.seconds is not None else (None if recording else 3.0)
    try:
        view = View(width=width, height=height, panels=args.frames, max_draw=args.max_draw,
                    elev=args.elev, azim=args.azim)
        figures = render(args.scene, args.out, seconds=seconds, fps=args.fps, dt=args.dt,
                         params=params, view=view, topic=args.topic)
    except (SceneError, ValueError, ImportError) as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    if recording:
        print(f"{args.out}: {figures['points']} points in {figures['bodies']} bodies, "
              f"{figures['frames']} frames read from {args.scene} in "
              f"{figures['simulate_s']:.2f} s, drawn in {figures['draw_s']:.2f} s, "
              f"{figures['bytes'] / 1024:.0f} KiB")
        return 0
    print(f"{args.out}: {figures['points']} points in {figures['bodies']} bodies, "
          f"{seconds:g} s simulated in {figures['simulate_s']:.2f} s "
          f"({figures['step_ms']:.2f} ms/step), drawn in {figures['draw_s']:.2f} s, "
          f"{figures['bytes'] / 1024:.0f} KiB")
    return 0


if __name__ == '__main__':
    sys.exit(main())
