"""``python -m apf_swarm_nodes.cli``: the ``apf-swarm`` command."""

import sys

from .parser import main

sys.exit(main())
