#!/usr/bin/env python3
"""Run the workspace's benchmarks with one command.

    python bench/run_all.py [--quick] [NAME ...]

Runs every ``bench/bench_<NAME>.py`` (all of them, or only the NAMEs given, e.g.
``simulator``) in its own interpreter -- the one running this script -- from the workspace
root, with ``src/apf_swarm_core`` prepended to ``PYTHONPATH`` and ``--quick`` passed on. Each
benchmark prints its own Markdown tables. Benchmarks of the ROS graph need the ROS
environment (``source scripts/activate.sh`` first); the simulator benchmark needs numpy only.
Exit status: 1 if any benchmark fails a floor or crashes, else 0.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str]) -> int:
    flags = [a for a in argv if a.startswith('-')]
    names = [a for a in argv if not a.startswith('-')]
    if any(f != '--quick' for f in flags):
        print(__doc__, file=sys.stderr)
        return 2
    scripts = sorted((ROOT / 'bench').glob('bench_*.py'))
    if names:
        scripts = [s for s in scripts if s.stem[len('bench_') :] in names]
        if len(scripts) != len(set(names)):
            print(f'unknown benchmark among {names}', file=sys.stderr)
            return 2
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        [str(ROOT / 'src' / 'apf_swarm_core')]
        + ([env['PYTHONPATH']] if env.get('PYTHONPATH') else [])
    )
    status = 0
    for script in scripts:
        print(f'\n## {script.relative_to(ROOT)}\n', flush=True)
        rc = subprocess.call([sys.executable, str(script), *flags], cwd=ROOT, env=env)
        if rc:
            print(f'\n{script.name} exited with status {rc}', flush=True)
            status = 1
    return status


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
