#!/usr/bin/env python3
"""The ROS graph's lockstep steps/s and control latency against the raw ping-pong: the
``lockstep`` and ``latency`` parts of ``bench_scale.py`` (same options), through the bring-up.

    source scripts/activate.sh
    python bench/bench_graph.py [--quick | --smoke] [--keep DIR]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_scale import main

if __name__ == '__main__':
    args = sys.argv[1:]
    sys.exit(main(args if '--only' in args else ['--only', 'lockstep,latency', *args]))
