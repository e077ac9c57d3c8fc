"""
``python -m sm_ros.bench profile``: where the time of a scene's ticks goes (cProfile).

Builds ``Simulation({'scene': SCENE})`` as the node does, runs ``--warmup`` ticks (so that
compiling or loading the kernels is not in the profile), then profiles ``--ticks`` ticks
with the standard library's cProfile and prints the ``--top`` entries sorted by
``--sort`` (``tottime``: time inside the function itself; ``cumulative``: with what it
calls). Compiled kernels show as one entry each: the profile says which Python call paid
for which kernel, not what happens inside it. ``--out FILE`` also saves the raw profile for
``python -m pstats FILE`` or snakeviz::

    python -m sm_ros.bench profile --scene many --ticks 120 --top 25
"""

import argparse
import cProfile
import io
import pstats
import sys
from typing import List, Optional


def add_arguments(parser: argparse.ArgumentParser):
    """Add the flags of the ``profile`` subcommand."""
    parser.add_argument('--scene', default='default', help='bundled scene name or scene file')
    parser.add_argument('--ticks', type=int, default=120, help='ticks profiled')
    parser.add_argument('--warmup', type=int, default=5, help='ticks run before profiling')
    parser.add_argument('--top', type=int, default=20, help='entries printed')
    parser.add_argument('--sort', choices=('tottime', 'cumulative', 'ncalls'), default='tottime')
    parser.add_argument('--out', default='', help='also save the raw profile to this file')


def profile_ticks(scene: str, ticks: int, warmup: int = 5) -> pstats.Stats:
    """Profile ``ticks`` ticks of ``scene`` after ``warmup`` ticks; return the statistics."""
    from sm_ros.sim import Simulation
    sim = Simulation({'scene': scene})
    for _ in range(warmup):
        sim.tick()
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(ticks):
        sim.tick()
    prof.disable()
    return pstats.Stats(prof)


def report(stats: pstats.Stats, top: int, sort: str) -> str:
    """The ``top`` entries of ``stats`` sorted by ``sort``, as pstats prints them."""
    buf = io.StringIO()
    stats.stream = buf
    stats.strip_dirs().sort_stats(sort).print_stats(top)
    return buf.getvalue()


def main(argv: Optional[List[str]] = None) -> int:
    """Entry point of ``python -m sm_ros.bench profile``."""
    parser = argparse.ArgumentParser(prog='python -m sm_ros.bench profile', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    args = parser.parse_args(argv)
    if args.ticks < 1:
        parser.error('--ticks must be at least 1')
    stats = profile_ticks(args.scene, args.ticks, args.warmup)
    if args.out:
        stats.dump_stats(args.out)
    print(f'{args.scene}: {args.ticks} ticks after {args.warmup} warm-up ticks')
    print(report(stats, args.top, args.sort))
    return 0


if __name__ == '__main__':
    sys.exit(main())
