#!/usr/bin/env python3
"""Lockstep steps/s, control latency against the raw ping-pong: bench_scale's two parts."""

import sys

from bench_scale import main

if __name__ == '__main__':
    sys.exit(main(['--only', 'lockstep,latency', *sys.argv[1:]]))  # a given --only wins
