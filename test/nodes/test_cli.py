"""The apf-swarm command as a user runs it: the installed executable in a subprocess."""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from apf_swarm_core.metrics import SUMMARY_KEYS

APF = shutil.which('apf-swarm')
pytestmark = pytest.mark.skipif(
    APF is None, reason='apf-swarm is not on PATH: source scripts/activate.sh (make test does)'
)


def run(*args: str, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [APF, *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, 'PYTHONWARNINGS': 'ignore'},
    )


def test_simulate_writes_schema(tmp_path: Path) -> None:
    out = tmp_path / 'run'
    p = run(
        'simulate', '--preset', 'triangle', '--duration', '6', '--seed', '3', '--out', str(out)
    )
    assert p.returncode == 0, p.stderr
    with np.load(out / 'trajectory.npz') as z:
        T = z['t'].shape[0]
        assert T == 6000
        for key, shape in {
            'x': (T, 3, 3),
            'v': (T, 3, 3),
            'u': (T, 3, 3),
            's': (T, 3, 3),
            'target_x': (T, 3),
            'target_v': (T, 3),
        }.items():
            assert z[key].shape == shape, key
    s = json.loads((out / 'summary.json').read_text())
    assert tuple(s) == SUMMARY_KEYS  # the simulator's schema, in order
    assert s['seed'] == 3 and s['n_trackers'] == 3 and s['duration'] == pytest.approx(6.0)
    assert set(s['formation']) == {
        'pair_distance_min',
        'pair_distance_max',
        'pair_distance_mean',
        'pair_distance_expected',
        'error_rms_steady',
        'closest_approach',
    }
    # the triangle forms: pair distances within 1 % of sqrt(c ln(b/(a + k_n/(3 k_f))))
    d = np.sqrt(1.7 * np.log(6.0 / (1.0 + 1.0 / 3.0)))
    assert s['formation']['pair_distance_expected'] == pytest.approx(d, rel=1e-9)
    assert s['formation']['pair_distance_min'] > 0.99 * d
    assert s['formation']['pair_distance_max'] < 1.01 * d
    assert s['converged'] is True
    assert 'centroid error' in p.stdout  # the summary is printed
    assert 'flight ' not in p.stdout  # lockstep: no realtime loop to judge
    assert (out / 'config.yaml').is_file()


def test_simulate_judges_an_emulated_realtime_loop_by_flight(tmp_path: Path) -> None:
    """With --control-rate the run is judged as a realtime run is: the triangle at 50 Hz
    with 5 ms flies; with 0.5 s of latency at 10 Hz it does not."""
    lines = {}
    for name, rate, latency in (('holds', '50', '0.005'), ('lost', '10', '0.5')):
        p = run(
            'simulate', '--preset', 'realtime', '--duration', '6', '--control-rate', rate,
            '--latency', latency, '--out', str(tmp_path / name), '--quiet',
        )  # fmt: skip
        assert p.returncode == 0, p.stderr
        lines[name] = [x for x in p.stdout.splitlines() if x.startswith('  flight ')]
    assert len(lines['holds']) == 1 and 'flight           flies: ' in lines['holds'][0], lines
    assert len(lines['lost']) == 1 and 'does not fly: ' in lines['lost'][0], lines
    # and summary.json keeps the verdict with the numbers it was judged by
    kept = {k: json.loads((tmp_path / k / 'summary.json').read_text())['flight'] for k in lines}
    assert kept['holds']['flies'] is True and kept['lost']['flies'] is False, kept
    assert kept['holds']['closest_pair'] >= 0.9, kept


def test_simulate_set_and_law(tmp_path: Path) -> None:
    p = run(
        'simulate',
        '--preset',
        'triangle',
        '--law',
        'traditional',
        '--set',
        'gamma=0.5',
        '--set',
        'n_trackers=2',
        '--duration',
        '2',
        '--out',
        str(tmp_path),
        '--quiet',
    )
    assert p.returncode == 0, p.stderr
    s = json.loads((tmp_path / 'summary.json').read_text())
    assert s['law'] == 'traditional' and s['n_trackers'] == 2
    cfg = (tmp_path / 'config.yaml').read_text()
    assert 'gamma: 0.5' in cfg


def test_check_exit_codes() -> None:
    ok = run('check', '--preset', 'triangle')
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert 'verdict: consistent' in ok.stdout
    paper = run('check', '--preset', 'paper', '--no-run')
    assert paper.returncode == 1
    assert 'no triangle exists' in paper.stdout and 'beta = 2 < v_N = 10' in paper.stdout
    js = run('check', '--preset', 'paper', '--no-run', '--json')
    rep = json.loads(js.stdout)
    assert rep['exit_code'] == 1
    assert {f['code'] for f in rep['findings'] if f['level'] == 'warning'} >= {
        'beta_vs_vn',
        'formation',
    }


def test_design_matches_formula() -> None:
    p = run('design', '--spacing', '2.0', '--json')
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    # inverse of d = sqrt(c ln(b/(a + k_n/(3 k_f)))): b = (a + k_n/(3k_f)) e^{d^2/c}
    assert out['b'] == pytest.approx((1 + 1 / 3) * np.exp(4.0 / 1.7), rel=1e-12)
    assert out['pair_distances'] == pytest.approx([2.0, 2.0, 2.0], abs=1e-6)
    p = run('design', '--spacing', '1.5', '--solve', 'c')
    assert p.returncode == 0 and 'c = ' in p.stdout


def test_sweep_csv_and_png(tmp_path: Path) -> None:
    p = run(
        'sweep',
        '--param',
        'gamma',
        '--values',
        '0.05,0.5',
        '--seeds',
        '2',
        '--duration',
        '4',
        '--out',
        str(tmp_path),
        '--quiet',
    )
    assert p.returncode == 0, p.stderr
    rows = list(csv.DictReader((tmp_path / 'sweep.csv').open()))
    assert len(rows) == 2 * 2 * 2  # laws x values x seeds
    prop = {
        float(r['value']): float(r['centroid_rms'])
        for r in rows
        if r['law'] == 'proposed' and r['seed'] == '1'
    }
    # docs/THEORY.md section 2: the lag grows with gamma, about v / (k_n (alpha + beta/gamma))
    assert prop[0.5] > 5 * prop[0.05]
    assert (tmp_path / 'sweep_tradeoff.png').stat().st_size > 10_000


@pytest.mark.parametrize(
    'args, needle',
    [
        (('simulate', '--preset', 'nope', '--out', 'X'), "unknown preset 'nope'"),
        (
            ('simulate', '--preset', 'triangle', '--set', 'gama=1', '--out', 'X'),
            'did you mean gamma',
        ),
        (('simulate', '--preset', 'triangle', '--set', 'beta=-1', '--out', 'X'), 'beta = -1.0'),
        (('simulate', '--preset', 'triangle', '--set', 'law=fuzzy', '--out', 'X'), 'law'),
        (('simulate', '--preset', 'triangle', '--n-trackers', '0', '--out', 'X'), 'n_trackers'),
        (('simulate', '--preset', 'triangle', '--set', 'novalue', '--out', 'X'), 'KEY=VALUE'),
        (('simulate', '--config', '/nonexistent.yaml', '--out', 'X'), 'does not exist'),
        (('simulate', '--preset', 'triangle', '--duration', '-1', '--out', 'X'), '--duration'),
        (('check', '--config', '__BADYAML__'), 'not valid YAML'),
        (('check', '--config', '__NOPARAMS__'), 'ros__parameters'),
        (('sweep', '--param', 'nokey', '--values', '1,2', '--out', 'X'), "unknown key 'nokey'"),
        (('sweep', '--param', 'gamma', '--values', '0.1,,2', '--out', 'X'), 'empty value'),
        (('sweep', '--param', 'gamma', '--values', '-1', '--out', 'X'), 'gamma'),
        (('design', '--spacing', '1', '--solve', 'c', '--set', 'b=0.6'), 'no c gives a triangle'),
        (('simulate', '--out', 'X'), 'one of the arguments --preset --config is required'),
    ],
)
def test_error_paths_exit_2_without_traceback(
    tmp_path: Path, args: tuple[str, ...], needle: str
) -> None:
    bad = tmp_path / 'bad.yaml'
    bad.write_text('/**:\n  ros__parameters: [unclosed\n')
    nop = tmp_path / 'nop.yaml'
    nop.write_text('/**:\n  gamma: 1\n')
    args = tuple(
        str(bad)
        if a == '__BADYAML__'
        else str(nop)
        if a == '__NOPARAMS__'
        else str(tmp_path / 'out')
        if a == 'X'
        else a
        for a in args
    )
    p = run(*args)
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert 'Traceback' not in p.stderr
    errors = [line for line in p.stderr.splitlines() if 'error:' in line]
    assert len(errors) == 1 and needle in errors[0], p.stderr  # one line names the problem
    assert p.stderr.splitlines()[-1] == errors[0]  # (argparse prints its usage above it)


def test_latency_file_is_a_list_or_a_run_summary(tmp_path: Path) -> None:
    """``--latency FILE`` reads a list, a realtime run's summary.json (``flight_check``), or
    one written before that key was named (``prediction``); anything else is refused by name."""
    from apf_swarm_core.errors import ApfSwarmError
    from apf_swarm_nodes.cli.commands import latency_samples

    docs = {
        'list': [0.004, 0.006],
        'summary': {'flight_check': {'latency_samples': [0.004, 0.006]}},
        'older': {'prediction': {'latency_samples': [0.004, 0.006]}},
    }
    for name, doc in docs.items():
        (tmp_path / name).write_text(json.dumps(doc))
        assert latency_samples(tmp_path / name).tolist() == [0.004, 0.006], name
    for bad in ({'flight_check': {}}, ['4 ms', 'fast'], [[0.004], [0.005, 0.006]], [-0.001]):
        (tmp_path / 'bad').write_text(json.dumps(bad))
        with pytest.raises(ApfSwarmError, match='latency_samples'):
            latency_samples(tmp_path / 'bad')
