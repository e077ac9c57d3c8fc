"""
Draw doc/img/architecture.png: the rooms of sm_ros and the data path between them.

The diagram's source is the two tables below (boxes with the files they stand for, and
arrows); edit them and run ``python tools/architecture_diagram.py`` (needs matplotlib, the
``plot`` extra). ``test/test_architecture.py`` checks that every file named here exists and
that doc/architecture.md names every box.
"""

import argparse
from pathlib import Path
import sys
from typing import Dict, List, Optional, Sequence, Tuple

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / 'doc' / 'img' / 'architecture.png'

#: name -> (column, row, title, files). Rows: 2 top, 1 the data path, 0 the solver.
BOXES: Dict[str, Tuple[float, float, str, Tuple[str, ...]]] = {
    'scene_file': (0, 1, 'scene file', ('config/scenes/*.yaml', 'config/meshes/')),
    'loader': (1, 1, 'scene loader', ('sm_ros/scene.py', 'sm_ros/scene_spec.py',
                                      'sm_ros/scene_build.py', 'sm_ros/shapes.py')),
    'params': (2, 2, 'parameter table', ('sm_ros/params.py',)),
    'sim': (2, 1, 'Simulation (no ROS)', ('sm_ros/sim.py', 'sm_ros/inputs.py',
                                          'sm_ros/stats.py')),
    'world': (2, 0, 'world and bodies', ('sm_ros/core/world.py', 'sm_ros/core/body.py',
                                         'sm_ros/core/clusters.py',
                                         'sm_ros/core/params.py')),
    'kernels': (3, 0, 'kernels (Numba)', ('sm_ros/core/kernels/', 'sm_ros/core/contact.py',
                                          'sm_ros/core/flat.py', 'sm_ros/core/pose.py')),
    'node': (3, 1, 'node (ROS adapter)', ('sm_ros/node.py', 'sm_ros/outputs.py',
                                          'sm_ros/startup.py', 'sm_ros/cloud.py',
                                          'sm_ros/markers.py', 'sm_ros/diagnostics.py')),
    'inputs': (3, 2, 'ROS inputs', ('force, grab, release', 'cloud_in, parameters',
                                    'services')),
    'messages': (4, 1, 'messages', ('points, poses, markers', '/diagnostics, /clock')),
    'viewers': (4, 0, 'live view, recorder', ('sm_ros/live.py', 'sm_ros/record.py')),
}

#: Distance between two columns and two rows (plot units).
DX, DY = 2.15, 1.5

#: (from, to, label)
ARROWS: Tuple[Tuple[str, str, str], ...] = (
    ('scene_file', 'loader', 'YAML'),
    ('loader', 'sim', 'World, BodyMeta'),
    ('params', 'loader', 'overrides'),
    ('params', 'sim', 'values, checks'),
    ('params', 'node', 'declares'),
    ('sim', 'world', 'tick: step(dt)'),
    ('world', 'kernels', 'arrays'),
    ('sim', 'node', 'tick listener'),
    ('inputs', 'node', ''),
    ('node', 'messages', ''),
    ('sim', 'viewers', 'each tick'),
)


def files() -> List[str]:
    """Return every repository path the boxes name (entries under sm_ros/ or config/)."""
    return [f for (_, _, _, fs) in BOXES.values() for f in fs
            if f.startswith(('sm_ros/', 'config/'))]


def draw(out: Path = OUT) -> Path:
    """Draw the diagram into ``out`` (PNG) and return the path."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyBboxPatch

    width, height = 1.78, 1.08          # a box, in plot units
    fig, ax = plt.subplots(figsize=(14, 6.6), dpi=100)
    ax.set_xlim(-1.0, 4 * DX + 1.0)
    ax.set_ylim(-0.95, 2 * DY + 0.65)
    ax.set_aspect('equal')
    ax.axis('off')
    for name, (col, row, title, fs) in BOXES.items():
        col, row = col * DX, row * DY
        solver = name in ('world', 'kernels')
        ax.add_patch(FancyBboxPatch(
            (col - width / 2, row - height / 2), width, height,
            boxstyle='round,pad=0.02,rounding_size=0.06', linewidth=1.2,
            edgecolor='#2b4c7e', facecolor='#dce8f7' if solver else '#f4f6f8'))
        ax.text(col, row + height / 2 - 0.12, title, ha='center', va='center',
                fontsize=10, fontweight='bold')
        ax.text(col, row - 0.08, '\n'.join(fs), ha='center', va='center', fontsize=8,
                family='monospace', linespacing=1.25)
    for a, b, label in ARROWS:
        (x0, y0), (x1, y1) = _at(a), _at(b)
        start, end = _edge(x0, y0, x1, y1, width, height), _edge(x1, y1, x0, y0, width,
                                                                 height)
        ax.annotate('', xy=end, xytext=start,
                    arrowprops=dict(arrowstyle='->', color='#444444', lw=1.3))
        if label:
            ax.text((start[0] + end[0]) / 2, (start[1] + end[1]) / 2 + 0.07, label,
                    ha='center', va='bottom', fontsize=8, color='#444444',
                    bbox=dict(facecolor='white', edgecolor='none', pad=0.5))
    ax.text(2 * DX, -0.85, 'shaded: sm_ros/core, the solver (no ROS); arrows: who calls or '
            'feeds whom', ha='center', fontsize=8.5, color='#555555')
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, bbox_inches='tight')
    plt.close(fig)
    return out


def _at(name: str) -> Tuple[float, float]:
    """Return the centre of a box in plot units."""
    return BOXES[name][0] * DX, BOXES[name][1] * DY


def _edge(x0: float, y0: float, x1: float, y1: float, w: float, h: float
          ) -> Tuple[float, float]:
    """Return where the line from box centre (x0, y0) towards (x1, y1) leaves the box."""
    dx, dy = x1 - x0, y1 - y0
    scale = min(w / 2 / abs(dx) if dx else float('inf'), h / 2 / abs(dy) if dy else
                float('inf'))
    return x0 + dx * scale, y0 + dy * scale


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Draw the diagram (``--out`` to put it elsewhere)."""
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument('--out', type=Path, default=OUT)
    args = ap.parse_args(argv)
    missing = [f for f in files() if not list(ROOT.glob(f.rstrip('/')))]
    if missing:
        print(f'files named in the diagram do not exist: {missing}', file=sys.stderr)
        return 1
    print(draw(args.out))
    return 0


if __name__ == '__main__':
    sys.exit(main())
