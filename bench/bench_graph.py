#!/usr/bin/env python3
"""The ROS graph's lockstep steps/s and control latency against the raw ping-pong: the
``lockstep`` and ``latency`` parts of ``bench_scale.py`` (same options), through the bring-up."""

import sys

from bench_scale import main

if __name__ == '__main__':
    sys.exit(main(['--only', 'lockstep,latency', *sys.argv[1:]]))  # a given --only wins
