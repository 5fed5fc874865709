#!/usr/bin/env python3
"""Bring up the ROS 2 swarm (target, plant, one tracker process per UAV) and record a run.

    source scripts/activate.sh
    python scripts/swarm_up.py --preset triangle --duration 3 --out runs/up

Same as ``apf-swarm up ...``; the logic is in ``apf_swarm_nodes.bringup`` (``--help`` lists
every option). Exit codes: 0 success, 2 bad input or graph not ready, 3 a node died,
4 stalled, 130 interrupted.
"""

import sys

try:
    from apf_swarm_nodes.bringup import main
except ImportError as exc:  # pragma: no cover - only without the workspace environment
    sys.stderr.write(
        f'swarm_up.py: error: {exc}; run `make setup` and `source scripts/activate.sh` first\n'
    )
    sys.exit(2)

if __name__ == '__main__':
    sys.exit(main(prog='swarm_up.py'))
