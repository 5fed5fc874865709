"""The compiled kernels (apf_swarm_core.kernels): compiled once, for the types the hot path
passes, so that no control step compiles (a compile takes seconds: a missed deadline)."""

import numpy as np
from apf_swarm_core.agents import TrackerAgent
from apf_swarm_core.formation import design_formation
from apf_swarm_core.gradients import gradient
from apf_swarm_core.laws import (
    filter_step,
    layer_switching_force,
    sliding_surface_proposed,
    sliding_surface_traditional,
    switching_force,
)
from apf_swarm_core.newton import block_direction, hessian_blocks
from apf_swarm_core.plant import plant_step
from apf_swarm_core.simulator import BatchSimulator

from apf_swarm_core import kernels, load_preset

KERNELS = (
    kernels.gradient_rows,
    kernels.hessian_rows,
    kernels.block_steps,
    kernels.block_rows,
    kernels.smc_rows,
    kernels.plant_rows,
    kernels.known_array,
    kernels.filter_array,
    kernels.surface_array,
    kernels.switching_array,
    kernels.simulate_steps,
)


def _signatures() -> list[int]:
    return [len(k.signatures) for k in KERNELS]


def test_warm_compiles_every_type_the_hot_path_passes():
    kernels.warm()
    before = _signatures()
    assert all(before), before
    # read-only and strided inputs (broadcast targets, views) as callers pass them
    cfg = load_preset('realtime').replace(n_trackers=5)
    x = design_formation(cfg).relative_positions + np.array([0.0, 0.0, 5.0])
    target = np.broadcast_to(np.array([0.0, 0.0, 5.0]), (3,))
    agent = TrackerAgent(cfg, 2)
    ids = [1, 2, 3, 4, 5]
    agent.offer_swarm(-1, ids, x, np.zeros((5, 3)), [True] * 5, target, target, 0.0, 0.0, seq=1)
    agent.command(-1)
    p = cfg.potential_params()
    gradient(x[::1], target, **p, rows=2)
    gradient(np.stack([x, x]), target, **{**p, 'b': np.array([6.0, 7.0])})
    blocks = hessian_blocks(x, **p, rows=[0, 1])
    block_direction(blocks, gradient(x, target, **p, rows=[0, 1]), target, k_n=1.0, mu=0.01)
    ro = np.broadcast_to(x, (2, 5, 3))
    plant_step(ro, ro, ro, mass=np.ones((2, 5, 3)), dt=1e-3, drag=np.array([0.1, 0.2]))
    plant_step(x, x, x, mass=1.0, dt=1e-3, drag=0.1, disturbance=0.0)
    # the public laws (the brake's switching force among them) on the same compiled functions
    switching_force(ro, ro, u0=25.0, drag=0.1)
    layer_switching_force(x, x, u0=25.0, phi=0.5)
    sliding_surface_proposed(x, x, x, alpha=0.1, beta=2.0, gamma=0.2)
    sliding_surface_proposed(x, x, x, alpha=0.1, beta=2.0, gamma=0.2, saturation='continuous')
    sliding_surface_traditional(x, x, x, alpha=0.1)
    filter_step(x, x, beta=2.0, lambda_filter=0.1, dt=1e-3)
    for preset in ('paper', 'realtime'):
        BatchSimulator([load_preset(preset)]).run(50)
        BatchSimulator([load_preset(preset)]).run(50, record=False)
    assert _signatures() == before
    # and no kernel was ever compiled for a read-only or strided array (the recording views
    # of the simulator's loop, step-major views of its trajectory, are the one exception)
    for kernel in KERNELS[:-1]:
        for sig in kernel.signatures:
            arrays = [t for t in sig if hasattr(t, 'layout')]
            assert all(t.layout == 'C' and t.mutable for t in arrays), (kernel, sig)


def test_a_tracker_row_equals_the_row_of_all_rows_and_a_run_alone_its_batch_row():
    rng = np.random.default_rng(4)
    x = rng.normal(scale=2.0, size=(3, 9, 3))
    tx = rng.normal(size=(3, 3))
    p = {'k_n': 1.0, 'k_f': 1.0, 'a': 1.0, 'b': np.array([6.0, 20.0, 50.0]), 'c': 1.7}
    full = gradient(x, tx, **p)
    for r in range(3):
        alone = gradient(x[r], tx[r], **{**p, 'b': float(p['b'][r])})
        assert np.array_equal(alone, full[r])
        for i in range(9):
            assert np.array_equal(
                gradient(x[r], tx[r], **{**p, 'b': p['b'][r]}, rows=[i])[0], full[r, i]
            )
