"""The remedies the core's warnings propose: the core names no command, the command line
words them as the ``apf-swarm design`` command that computes them (the texts it prints)."""

from __future__ import annotations

from apf_swarm_core.checks import check_config
from apf_swarm_core.config_files import load_preset
from apf_swarm_core.sampled import predict
from apf_swarm_nodes.advice import CLI_ADVICE


def test_a_failing_rate_is_answered_with_the_design_command() -> None:
    cfg = load_preset('realtime').replace(
        n_trackers=8, latency=0.004, precondition='none', control_rate=100.0
    )
    assert not any('apf-swarm' in w for w in predict(cfg).warnings)
    cli = [w for w in predict(cfg, advice=CLI_ADVICE).warnings if 'predicted to fail' in w]
    assert cli[0].endswith(
        'raise the control rate, or run '
        '`apf-swarm design --control-rate 100 --latency 0.004 --n-trackers 8`'
    )


def test_a_narrow_layer_is_answered_with_the_design_command() -> None:
    cfg = load_preset('realtime').replace(
        latency=0.012, phi=0.25, control_rate=100.0, compensation='none'
    )
    cli = [w for w in predict(cfg, advice=CLI_ADVICE).warnings if 'too narrow' in w]
    assert cli[0].endswith('1/s, or run `apf-swarm design --control-rate 100 --latency 0.012`')
    assert not any('apf-swarm' in w for w in predict(cfg).warnings)


def test_a_collapsing_triangle_is_answered_with_the_spacing_design() -> None:
    cfg = load_preset('triangle')
    cfg = cfg.replace(b=0.5 * cfg.a)
    plain = [f.message for f in check_config(cfg).findings if f.code == 'formation']
    cli = [
        f.message for f in check_config(cfg, advice=CLI_ADVICE).findings if f.code == 'formation'
    ]
    assert cli[0].endswith('(apf-swarm design --spacing D gives b for a spacing D).')
    assert 'apf-swarm' not in plain[0]
