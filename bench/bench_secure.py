#!/usr/bin/env python3
"""What a secure multi-host run costs against an open one (the baseline): the ``secure``
part of ``bench_scale.py``, ``scripts/multihost.py --hosts 3`` with ``--open`` and with TLS.

    sudo python bench/bench_secure.py [--quick | --smoke] [--n-trackers 32 --duration 25]
        [--order open,secure] [--out DIR]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_scale import main

if __name__ == '__main__':
    names = {'--n-trackers': '--sizes', '--duration': '--flight', '--out': '--keep'}
    args = [names.get(a, a) for a in sys.argv[1:]]
    n, s = ('8', '10') if '--quick' in args else ('32', '25')
    sys.exit(main(['--only', 'secure', '--sizes', n, '--flight', s, *args]))
