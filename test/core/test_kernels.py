"""The compiled kernels (apf_swarm_core.kernels): compiled once, for the types the hot path
passes, so that no control step compiles (a compile takes seconds: a missed deadline)."""

import numpy as np
import pytest
from apf_swarm_core.agents import TrackerAgent
from apf_swarm_core.control import BlockPreconditioner
from apf_swarm_core.controller import SlidingModeController
from apf_swarm_core.formation import design_formation
from apf_swarm_core.gradients import gradient
from apf_swarm_core.laws import switching_force
from apf_swarm_core.newton import hessian_blocks
from apf_swarm_core.plant import plant_step
from apf_swarm_core.simulator import BatchSimulator
from reference import (
    block_direction,
    filter_step,
    layer_switching_force,
    sliding_surface_proposed,
    sliding_surface_traditional,
)

from apf_swarm_core import kernels, load_preset

KERNELS = (
    kernels.gradient_rows,
    kernels.hessian_rows,
    kernels.block_rows,
    kernels.smc_rows,
    kernels.plant_rows,
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
    hessian_blocks(x, **p, rows=[0, 1])
    ro = np.broadcast_to(x, (2, 5, 3))
    plant_step(ro, ro, ro, mass=np.ones((2, 5, 3)), dt=1e-3, drag=np.array([0.1, 0.2]))
    plant_step(x, x, x, mass=1.0, dt=1e-3, drag=0.1, disturbance=0.0)
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


@pytest.mark.parametrize(
    'law, saturation, switching, feedforward',
    [
        ('proposed', 'paper', 'sign', 0.0),
        ('proposed', 'paper', 'layer', 0.7),
        ('proposed', 'continuous', 'layer', 0.0),
        ('proposed', 'continuous', 'sign', 0.7),
        ('traditional', 'paper', 'sign', 0.7),
        ('traditional', 'paper', 'layer', 0.0),
    ],
)
def test_the_controller_kernel_computes_the_reference_laws(
    law, saturation, switching, feedforward
):
    """smc_rows against the numpy forms of eq. 22-28, 31 (the manifold on v - w v_ref), 24
    and 26, for a batch of runs with per-run gains, bit for bit."""
    rng = np.random.default_rng(6)
    gains = {'alpha': 0.3, 'beta': np.array([1.0, 2.0]), 'gamma': np.array([0.2, 0.5])}
    gains.update(lambda_filter=0.1, u0=25.0, drag=0.1, phi=0.4, feedforward=feedforward)
    ctl = SlidingModeController(
        law=law, dt=0.01, shape=(2, 4, 3), saturation=saturation, switching=switching, **gains
    )
    for _ in range(5):
        v, g = rng.normal(size=(2, 4, 3)), rng.normal(scale=0.4, size=(2, 4, 3))
        # the edges: a zero gradient, a zero component, a gradient exactly at the layer
        g[0, 0] = 0.0
        g[1, 1, 2] = 0.0
        v[0, 1] = 0.0
        g[0, 2] = (gains['gamma'][0], 0.0, 0.0)
        g[1, 3] = (0.0, -gains['gamma'][1], 0.0)
        vref = rng.normal(size=(2, 3))
        z = ctl.z
        out = ctl.step(v, g, vref)
        vs = v - np.asarray(feedforward) * vref[:, None, :] if feedforward else v
        if law == 'traditional':
            s = sliding_surface_traditional(vs, g, z, alpha=0.3)
        else:
            s, outside = sliding_surface_proposed(
                vs,
                g,
                z,
                alpha=0.3,
                beta=gains['beta'],
                gamma=gains['gamma'],
                saturation=saturation,
            )
            assert np.array_equal(out.saturated, outside)
        if switching == 'layer':
            force = layer_switching_force(s, v, u0=25.0, phi=0.4, drag=0.1)
        else:
            force = switching_force(s, v, u0=25.0, drag=0.1)
        assert np.array_equal(out.sliding_surface, s)
        assert np.array_equal(out.force, force)
        znext = filter_step(z, g, beta=gains['beta'], lambda_filter=0.1, dt=0.01)
        assert np.array_equal(ctl.z, znext)


_GAINS = {
    'law': 'proposed', 'dt': 0.01, 'shape': (3, 3), 'alpha': 0.3, 'beta': 1.0, 'gamma': 0.2,
    'lambda_filter': 0.1, 'u0': 25.0,
}  # fmt: skip


@pytest.mark.parametrize(
    'option, match',
    [
        ({'law': 'sliding'}, 'law must be one of'),
        ({'saturation': 'tanh'}, 'saturation must be one of'),
        ({'switching': 'relay'}, 'switching must be one of'),
    ],
)
def test_the_controller_refuses_an_unknown_option_on_construction(option, match):
    with pytest.raises(ValueError, match=match):
        SlidingModeController(**{**_GAINS, **option})


def test_the_controller_retunes_known_gains_only():
    ctl = SlidingModeController(**_GAINS)
    before = ctl.table.copy()
    ctl.retune(u0=40.0)
    assert ctl.u0 == 40.0 and not np.array_equal(ctl.table, before)
    with pytest.raises(TypeError, match='not a controller gain: k_n'):
        ctl.retune(k_n=2.0)


@pytest.mark.parametrize('trust', [0.0, 0.05])
def test_the_block_kernel_computes_the_reference_direction(trust):
    rng = np.random.default_rng(7)
    x, tx = rng.normal(scale=1.5, size=(7, 3)), rng.normal(size=3)
    p = {'k_n': 1.3, 'k_f': 0.8, 'a': 1.0, 'b': 6.0, 'c': 1.7}
    got = BlockPreconditioner(0.05, trust).direction(x, tx, p)
    gbar = 1.3 * (x.mean(axis=0) - tx)
    blocks, g = hessian_blocks(x, **p), gradient(x, tx, **p)
    want = block_direction(blocks, g, gbar, k_n=1.3, mu=0.05, trust=trust)
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)
    rows = BlockPreconditioner(0.05, trust).direction(x, tx, p, rows=[1, 4])
    assert np.array_equal(rows, got[[1, 4]])
