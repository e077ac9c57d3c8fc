"""Part 3 of the benchmark: the node end to end (filled in when the node is ready)."""

import argparse
from pathlib import Path
from typing import Any, Dict


def add_arguments(p: argparse.ArgumentParser):
    """Flags of the ``node`` subcommand."""
    p.add_argument('--node-sizes', default='1e4,1e5')
    p.add_argument('--node-rates', default='30,60')
    p.add_argument('--node-seconds', type=float, default=3.0)


def run(args, out: Path) -> Dict[str, Any]:
    """Not yet measured."""
    return {'status': 'not run'}
