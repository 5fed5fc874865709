#!/usr/bin/env python3
"""What the live view costs a realtime run: the ``view`` part of ``bench_scale.py``: rounds
of no ``--view`` (the baseline), a view nobody watches and a watching Foxglove client.

    python bench/bench_view.py [--n 8] [--duration 15] [--rounds 2] [--smoke]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_scale import main

if __name__ == '__main__':
    names = {'--n': '--sizes', '--duration': '--flight'}
    args = [names.get(a, a) for a in sys.argv[1:]]
    sys.exit(main(['--only', 'view', '--sizes', '8', '--flight', '15', *args]))
