"""Bit-for-bit invariants the fast paths rely on (a lockstep ROS run must reproduce the
simulator exactly, and sign() in sliding mode turns any rounding difference into another
trajectory): every check here is exact equality, not a tolerance."""

import numpy as np
import pytest
from apf_swarm_core.controller import SlidingModeController
from apf_swarm_core.gradients import gradient
from apf_swarm_core.plant import DisturbanceSource, plant_step
from apf_swarm_core.potential import pair_weight
from apf_swarm_core.simulator import TRAJECTORY_KEYS, BatchSimulator

from apf_swarm_core import load_preset, simulate, simulate_batch


def _params(rng, R=None):
    size = None if R is None else R
    return {
        'k_n': rng.uniform(0.2, 3.0, size),
        'k_f': rng.uniform(0.2, 3.0, size),
        'a': rng.uniform(0.2, 2.0, size),
        'b': rng.uniform(0.5, 8.0, size),
        'c': rng.uniform(0.3, 3.0, size),
    }


def _whole_array_gradient(x, xt, k_n, k_f, a, b, c):
    """The whole-array numpy form for one run (x (n, 3)) and the size of its terms (the
    scale of its rounding): d_ij, r^2, the weight, the sum over j."""
    d = x[:, None, :] - x[None, :, :]
    w = a - b * np.exp(np.add.reduce(d * d, axis=-1) / (-c))
    pair = np.add.reduce(d * w[..., None], axis=-2)
    size = np.abs(k_n * (x - xt)) + np.abs(k_f) * np.add.reduce(np.abs(d * w[..., None]), -2)
    return k_n * (x - xt) + k_f * pair, size


@pytest.mark.parametrize('unit', [False, True])
def test_three_tracker_gradient_agrees_with_the_whole_array_form_equals_its_rows(unit):
    rng = np.random.default_rng([3, unit])
    for trial in range(300):
        p = _params(rng)
        if unit:
            p.update(k_n=1.0, k_f=1.0)
        scale = 10.0 ** rng.uniform(-3, 2)
        x = rng.normal(scale=scale, size=(3, 3))
        if trial % 10 == 0:
            x[1] = x[0]  # coincident trackers: zero differences
        xt = rng.normal(scale=scale, size=3)
        full = gradient(x, xt, **p)
        # the compiled kernel against numpy: equal up to the rounding of the terms
        ref, size = _whole_array_gradient(x, xt, **p)
        assert np.all(np.abs(full - ref) <= 1e-14 * size + 1e-300), trial
        for i in range(3):
            assert np.array_equal(gradient(x, xt, **p, rows=[i])[0], full[i]), (trial, i)
        # prepared 0-d gains (what the simulator passes) give the same bits as floats
        p0 = {k: np.asarray(v, dtype=float) for k, v in p.items()}
        assert np.array_equal(gradient(x[None], xt[None], **p0)[0], full)


@pytest.mark.parametrize('n', [2, 3, 4, 5, 7])
@pytest.mark.parametrize('R', [5, 70])
def test_a_run_inside_a_batch_equals_the_run_alone(n, R):
    rng = np.random.default_rng([n, R, 7])
    x = rng.normal(scale=1.5, size=(R, n, 3))
    xt = rng.normal(size=(R, 3))
    per_run = _params(rng, R)
    shared = {k: float(v[0]) for k, v in per_run.items()}
    g_per_run = gradient(x, xt, **per_run)
    g_shared = gradient(x, xt, **shared)
    for r in range(R):
        alone = {k: float(v[r]) for k, v in per_run.items()}
        assert np.array_equal(g_per_run[r], gradient(x[r], xt[r], **alone)), r
        assert np.array_equal(g_shared[r], gradient(x[r], xt[r], **shared)), r
    for i in range(n):
        assert np.array_equal(gradient(x, xt, **per_run, rows=[i])[:, 0], g_per_run[:, i])


def test_pair_weight_forms_agree():
    rng = np.random.default_rng(11)
    r2 = rng.uniform(0, 20, size=(4, 5, 5))
    a, b, c = 1.3, 6.0, 1.7
    w = pair_weight(r2, a, b, c)
    assert np.array_equal(w, a - b * np.exp(r2 / (-c)))
    assert pair_weight(2.0, a, b, c) == a - b * np.exp(2.0 / (-c))


def test_the_layer_test_is_the_norm_test_exactly():
    """The controller's ``||g|| >= gamma`` (eq. 8) is np.linalg.norm's, for norms right at
    gamma and gammas of every scale, zero, subnormal, infinite, negative and NaN."""
    rng = np.random.default_rng(5)
    gammas = np.concatenate(
        [
            rng.uniform(1e-3, 10, 400),
            10.0 ** rng.uniform(-160, 150, 200),
            [0.0, 0.2, 1.0, 3.0, 5e-324, 1e-310, 1e300, np.inf, -1.0, np.nan],
        ]
    )
    R, m = gammas.size, 2000
    v = rng.normal(size=(R, m, 3))
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(all='ignore'):
        scale = np.where(np.isfinite(gammas) & (gammas > 0), gammas, 1.0)[:, None, None]
        v *= scale * (1 + rng.integers(-3, 4, size=(R, m, 1)) * 2.0**-52)
        ctl = SlidingModeController(
            law='proposed', alpha=0.1, beta=2.0, gamma=gammas, lambda_filter=0.1, u0=1.0, dt=0.01,
            shape=(R, m, 3),
        )  # fmt: skip
        out = ctl.step(np.zeros((R, m, 3)), v)
        want = np.linalg.norm(v, axis=-1) >= gammas[:, None]
    assert np.array_equal(out.saturated, want) and want.any() and not want.all()


@pytest.mark.parametrize(
    'law, saturation',
    [('proposed', 'paper'), ('traditional', 'paper'), ('proposed', 'continuous')],
)
def test_controller_on_one_row_equals_that_row_of_all_rows(law, saturation):
    rng = np.random.default_rng(9)
    gains = {
        'law': law,
        'alpha': 0.01,
        'beta': 2.0,
        'gamma': 0.2,
        'lambda_filter': 0.1,
        'u0': 125.0,
        'drag': 0.1,
        'dt': 1e-3,
        'saturation': saturation,
    }
    whole = SlidingModeController(**gains, shape=(3, 3))
    rows = [SlidingModeController(**gains, shape=(1, 3)) for _ in range(3)]
    for step in range(300):
        v = rng.normal(size=(3, 3))
        g = rng.normal(scale=0.3 if step % 2 else 0.05, size=(3, 3))
        out = whole.step(v, g)
        for i, ctl in enumerate(rows):
            o = ctl.step(v[i : i + 1], g[i : i + 1])
            for name in ('force', 'sliding_surface', 'filter_state', 'saturated'):
                assert np.array_equal(getattr(o, name)[0], getattr(out, name)[i]), (step, i)
    assert all(np.array_equal(ctl.z[0], whole.z[i]) for i, ctl in enumerate(rows))


def test_plant_step_in_place_and_allocating_paths_agree():
    rng = np.random.default_rng(2)
    x, v, u, d = (rng.normal(size=(4, 3, 3)) for _ in range(4))
    mass = rng.uniform(0.5, 1.5, size=(4, 3, 3))

    def formula(x, v, u, mass, drag, d, dt):
        acc = (u - drag * v - d) / mass
        return x + v * dt + 0.5 * dt * dt * acc, v + acc * dt

    for m in (mass, 1.0, np.asarray(1.0), np.ones((4, 3, 3)), 1.3):
        for drag in (0.1, np.asarray(0.1), np.array([0.1, 0.2, 0.0, 0.3])):
            dr = np.asarray(drag)[..., None, None] if np.ndim(drag) else drag
            want = formula(x, v, u, m, dr, d, 1e-3)
            got = plant_step(x, v, u, mass=m, dt=1e-3, drag=drag, disturbance=d)
            assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=False))
    # an unbatched state with a batched force: the allocating path
    got = plant_step(x[0], v[0], u, mass=1.0, dt=1e-3, drag=0.1, disturbance=0.0)
    want = formula(x[0], v[0], u, 1.0, 0.1, 0.0, 1e-3)
    assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=False))


@pytest.mark.parametrize('every', [1, 3])
def test_run_equals_repeated_steps(every):
    """run() inlines step() and copies the times and the target's samples in slices of its
    blocks: the same trajectory, bit for bit, over several target blocks and two calls."""
    cfg = load_preset('triangle').replace(duration=2.6, record_every=every)
    sim = BatchSimulator([cfg])
    rec = sim.run(1500)
    rec2 = sim.run(1100)
    ref = BatchSimulator([cfg])
    samples = {key: [] for key in (*TRAJECTORY_KEYS, 'saturated')}
    for k in range(2600):
        x, v = ref.x, ref.v
        out, tx, tv = ref.step()
        if k % every == 0:
            for key, val in (
                ('t', k * cfg.dt),
                ('x', x),
                ('v', v),
                ('u', out.force),
                ('s', out.sliding_surface),
                ('target_x', tx),
                ('target_v', tv),
                ('saturated', out.saturated),
            ):
                samples[key].append(np.copy(val))
    for key, vals in samples.items():
        got = np.concatenate([rec[key], rec2[key]], axis=0 if key == 't' else 1)
        want = np.array(vals) if key == 't' else np.stack(vals, axis=1)
        assert np.array_equal(got, want), key
    assert np.array_equal(sim.x, ref.x) and np.array_equal(sim.v, ref.v)
    assert np.array_equal(sim.controller.z, ref.controller.z) and sim.k == ref.k == 2600


def test_batch_and_single_runs_agree_bit_for_bit():
    base = load_preset('triangle').replace(duration=1.5)
    cfgs = [
        base,
        base.replace(seed=7, gamma=0.5),
        base.replace(seed=3, mass=(1.2,)),
        base.replace(seed=4, b=5.0),
    ]
    batch = simulate_batch(cfgs).trajectory
    for r, cfg in enumerate(cfgs):
        single = simulate(cfg).trajectory
        for key in (*TRAJECTORY_KEYS, 'saturated'):
            assert np.array_equal(batch[key] if key == 't' else batch[key][r], single[key]), (
                r,
                key,
            )


def test_disturbance_views_stay_valid():
    """Arrays handed out earlier are not overwritten by later refills (the plant node and
    the simulator may hold them past the next step)."""
    src = DisturbanceSource([1, 2], 3, [1.0, 1.0], block=4)
    first = [src.next() for _ in range(10)]
    kept = [f.copy() for f in first]
    for _ in range(20):
        src.next()
    assert all(np.array_equal(a, b) for a, b in zip(first, kept, strict=False))


@pytest.mark.parametrize(
    'preset, changes',
    [
        ('paper', {}),
        ('triangle', {'n_trackers': 5, 'law': 'traditional'}),
        ('triangle', {'saturation': 'continuous'}),
        ('realtime', {'n_trackers': 8}),  # layer switching, feed-forward, block direction
        ('realtime', {'n_trackers': 4, 'compensation': 'none', 'control_rate': 100.0}),
    ],
)
def test_compiled_loop_equals_the_step_by_step_path(preset, changes):
    """BatchSimulator.run's compiled loop (kernels.simulate_steps) and step() in a loop
    call the same compiled functions: the same bits, whatever the law, switching,
    direction or sampling."""
    cfg = load_preset(preset).replace(**changes)
    fast, slow = BatchSimulator([cfg]), BatchSimulator([cfg])
    assert fast._compiled()
    fast.run(1200, record=False)
    for _ in range(1200):
        slow.step()
    assert np.array_equal(fast.x, slow.x) and np.array_equal(fast.v, slow.v)
    assert np.array_equal(fast.controller.z, slow.controller.z)
    assert np.array_equal(fast.force, slow.force)
