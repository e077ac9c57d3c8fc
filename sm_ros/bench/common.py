"""
Shared helpers of the benchmark: lattices, timers, tables, plots and machine facts.

Nothing here imports rclpy; matplotlib is imported lazily (Agg backend) so that the
tables can be written where it is missing.
"""

import contextlib
import csv
import math
import os
from pathlib import Path
import platform
import subprocess
import sys
import time
from typing import Any, Dict, List, Optional, Sequence

import numpy as np


def lattice_side(n_points: float) -> int:
    """Side n of the n x n x n lattice whose n^3 is closest to ``n_points`` (log scale)."""
    n = max(2, int(round(float(n_points) ** (1.0 / 3.0))))
    best = min((n - 1, n, n + 1), key=lambda s: abs(math.log(max(s, 2) ** 3 / n_points)))
    return max(2, best)


def cube_lattice(n: int, size: float = 1.0, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """n^3 points on a regular lattice filling [0, size]^3 + origin (pypbd's layout)."""
    a = np.linspace(0.0, size, n)
    pts = np.stack(np.meshgrid(a, a, a, indexing='ij'), axis=-1).reshape(-1, 3)
    return pts + np.asarray(origin, dtype=float)


def box_lattice(size: Sequence[float], spacing: float, origin=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Points on a regular lattice filling the box [0, size] + origin."""
    axes = [np.linspace(0.0, s, max(2, int(round(s / spacing)) + 1)) for s in size]
    pts = np.stack(np.meshgrid(*axes, indexing='ij'), axis=-1).reshape(-1, 3)
    return pts + np.asarray(origin, dtype=float)


def time_calls(fn, *, min_time: float = 0.25, min_reps: int = 3, max_reps: int = 200,
               batch: int = 1) -> np.ndarray:
    """
    Seconds per call of ``fn()`` (one sample per batch of ``batch`` calls).

    Runs at least ``min_reps`` batches and keeps going until ``min_time`` seconds have
    passed (at most ``max_reps`` batches). The machine is shared: callers report the
    median and the minimum of the samples.
    """
    samples = []
    t_start = time.perf_counter()
    while True:
        t0 = time.perf_counter()
        for _ in range(batch):
            fn()
        samples.append((time.perf_counter() - t0) / batch)
        if len(samples) >= max_reps:
            break
        if len(samples) >= min_reps and time.perf_counter() - t_start >= min_time:
            break
    return np.asarray(samples)


def loglog_slope(x: Sequence[float], y: Sequence[float]) -> float:
    """Least-squares slope of log y against log x (NaN with fewer than two points)."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    ok = (x > 0) & (y > 0) & np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 2:
        return float('nan')
    return float(np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)[0])


def fmt(value: Any, digits: int = 3) -> str:
    """Short human formatting for table cells (significant digits; '-' for missing)."""
    if value is None:
        return '-'
    if isinstance(value, (bool, np.bool_)):
        return 'yes' if value else 'no'
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if not math.isfinite(v):
            return '-' if math.isnan(v) else str(v)
        if v == 0.0:
            return '0'
        if abs(v) >= 10 ** digits or abs(v) < 1e-3:
            return f'{v:.{max(digits - 1, 1)}e}'
        return f'{v:.{digits}g}'
    return str(value)


class Table:
    """Rows of dicts written as CSV (full precision) and markdown (short numbers)."""

    def __init__(self, name: str, columns: Sequence[str], title: str = ''):
        """Name the table (file stem), its columns and an optional markdown title."""
        self.name = name
        self.columns = list(columns)
        self.title = title
        self.rows: List[Dict[str, Any]] = []

    def add(self, **row):
        """Append one row (unknown keys are an error, missing ones are blank)."""
        unknown = set(row) - set(self.columns)
        if unknown:
            raise KeyError(f'{self.name}: unknown columns {sorted(unknown)}')
        self.rows.append(row)

    def markdown(self) -> str:
        """Return the table as GitHub markdown."""
        lines = []
        if self.title:
            lines += [f'### {self.title}', '']
        lines.append('| ' + ' | '.join(self.columns) + ' |')
        lines.append('|' + '|'.join(' --- ' for _ in self.columns) + '|')
        for r in self.rows:
            lines.append('| ' + ' | '.join(fmt(r.get(c)) for c in self.columns) + ' |')
        return '\n'.join(lines) + '\n'

    def write(self, out: Path) -> List[Path]:
        """Write ``<name>.csv`` and ``<name>.md`` into ``out``; return the paths."""
        out.mkdir(parents=True, exist_ok=True)
        csv_path = out / f'{self.name}.csv'
        with open(csv_path, 'w', newline='') as f:
            w = csv.DictWriter(f, fieldnames=self.columns)
            w.writeheader()
            for r in self.rows:
                w.writerow({c: r.get(c, '') for c in self.columns})
        md_path = out / f'{self.name}.md'
        md_path.write_text(self.markdown())
        return [csv_path, md_path]


def pyplot():
    """matplotlib.pyplot on the Agg backend, or None if matplotlib is missing."""
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    return plt


def save_figure(fig, path: Path) -> Path:
    """Save a figure as a small PNG (the docs keep them under 200 KB) and close it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    import matplotlib.pyplot as plt
    plt.close(fig)
    return path


def machine_info() -> Dict[str, Any]:
    """CPU, core count, library versions and the load average when the run started."""
    import numba
    info = {
        'python': platform.python_version(),
        'numpy': np.__version__,
        'numba': numba.__version__,
        'numba_threads': numba.get_num_threads(),
        'numba_threading_layer': _threading_layer(),
        'cpus': os.cpu_count(),
        'cpu': _cpu_name(),
        'platform': platform.platform(),
    }
    try:
        info['loadavg_1min'] = round(os.getloadavg()[0], 2)
    except OSError:
        pass
    return info


def _threading_layer() -> str:
    import numba
    try:
        return numba.threading_layer()
    except ValueError:
        return 'not initialised'


def _cpu_name() -> str:
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or 'unknown'


def run_json_subprocess(cmd: List[str], timeout: float, cwd: Optional[str] = None,
                        env: Optional[Dict[str, str]] = None) -> Optional[Dict[str, Any]]:
    """Run ``cmd``; return the JSON object on its last stdout line, or None on failure."""
    import json
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=cwd,
                             env=env)
    except (subprocess.TimeoutExpired, OSError) as exc:
        print(f'  [skip] {cmd[1] if len(cmd) > 1 else cmd[0]}: {exc}', file=sys.stderr)
        return None
    lines = [ln for ln in res.stdout.splitlines() if ln.strip().startswith('{')]
    if res.returncode != 0 or not lines:
        tail = (res.stderr or res.stdout).strip().splitlines()[-1:] or ['no output']
        print(f'  [skip] exit {res.returncode}: {tail[0][:200]}', file=sys.stderr)
        return None
    try:
        return json.loads(lines[-1])
    except ValueError:
        return None


_T0 = time.perf_counter()


def log(msg: str):
    """Progress line on stderr with the elapsed time (stdout stays for the summary)."""
    print(f'{time.perf_counter() - _T0:7.1f}s {msg}', file=sys.stderr, flush=True)


def as_list(text: Optional[str], cast=float) -> List[Any]:
    """'1e3,1e4' -> [1000.0, 10000.0] (cast applied to each item)."""
    if text is None or text == '':
        return []
    return [cast(t) for t in str(text).split(',') if t.strip()]


def ints(text: str) -> List[int]:
    """'1,2,4' -> [1, 2, 4] (accepts 1e3-style numbers)."""
    return [int(float(t)) for t in as_list(text, str)]



@contextlib.contextmanager
def one_numba_thread():
    """Run the block with Numba on one thread (solver time, not parallel speed-up)."""
    import numba
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(threads)
