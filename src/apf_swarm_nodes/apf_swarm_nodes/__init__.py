"""The ROS 2 layer of apf_swarm: nodes, bring-up, bag tools and the ``apf-swarm`` command.

Importing the package keeps numpy's BLAS to one thread per process (unless the environment
says otherwise): every node process runs one control loop, and OpenBLAS's worker threads,
which spin while they wait, would fight the swarm's other processes for the cores (the
Newton preconditioner's eigendecomposition is the one BLAS call on the control path).
"""

import os

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')
