"""A realtime run's flight check: the sampled-data prediction before the run (gains
scheduled if needed) and, after it, the run judged beside its headless emulation with the
run's own delays (summary.json ``flight_check``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from apf_swarm_core.config import DEFAULT_LATENCY, REALTIME_RATE, SwarmConfig

from .commands import Plan

__all__ = ['FlightCheck']


class FlightCheck:
    """A realtime run's flight check: :meth:`check` before the run, :meth:`judged` after."""

    def __init__(self, plan: Plan, say: Callable[[str], None]) -> None:
        self.plan, self.say = plan, say
        #: what the probe implies for this run (:func:`~..capacity.probe.derive`)
        self.capacity: dict[str, Any] | None = None
        #: the sampled-data prediction before the run, None until :meth:`check`
        self.prediction: Any = None
        self.gains_scheduled: dict[str, Any] = {}
        self.cfg: SwarmConfig | None = None

    def check(self, cfg: SwarmConfig) -> SwarmConfig:
        """The sampled-data prediction (printed, kept); returns the configuration to fly,
        with designed gains under ``--gains auto`` if its own would fail."""
        from apf_swarm_core.sampled import predict, schedule_gains

        from ..advice import CLI_ADVICE
        from ..capacity import probe

        n = cfg.n_trackers
        machine = probe.ensure_or_warn(
            self.say, f'assuming {REALTIME_RATE:g} Hz and {DEFAULT_LATENCY * 1e3:g} ms of latency'
        )
        measured = (
            probe.derive(machine, n, cfg.control_rate or None, self.plan.trackers_per_process)
            if machine
            else {'rate': cfg.control_rate or REALTIME_RATE, 'latency': None, 'capacity': {}}
        )
        self.capacity = measured
        if cfg.control_rate <= 0:
            cfg = cfg.replace(control_rate=measured['rate'])
            self.say(
                f'control rate {measured["rate"]:g} Hz for {n} trackers on this '
                f'machine (`apf-swarm probe`)'
            )
        latency = cfg.latency or measured['latency'] or DEFAULT_LATENCY
        fits = measured['capacity'].get(f'{cfg.control_rate:g}')
        lowest = min(cfg.control_rate, probe.RATES[-1])  # the run's, if lower
        most = probe.largest_swarm(machine, lowest) if machine else None
        if most is not None and n > most:
            self.say(
                f'warning: {n} trackers cannot fly on this machine: at {lowest:g} '
                f'Hz, the lowest rate it runs them at, {most} fit in '
                f'{probe.CPU_BUDGET:.0%} of its cores (`apf-swarm probe`); fly at most {most} '
                'here, or spread the swarm over hosts (scripts/multihost.py)'
            )
        elif fits is not None and n > fits:
            self.say(
                f'warning: {n} trackers at {cfg.control_rate:g} Hz are more than '
                f"the {fits} that fit in {probe.CPU_BUDGET:.0%} of this machine's cores "
                f'(`apf-swarm probe`): expect late commands; a lower rate (--set '
                f'control_rate=HZ: '
                + ', '.join(f'{v} at {k} Hz' for k, v in measured['capacity'].items())
                + ') or fewer trackers'
            )
        base = cfg
        if self.plan.gains == 'auto':
            cfg, pred, gains, warnings = schedule_gains(cfg, latency=latency, advice=CLI_ADVICE)
        else:
            pred = predict(cfg, latency=latency, advice=CLI_ADVICE)
            gains, warnings = None, list(pred.warnings)
        if gains:
            self.say(
                f'scheduled gains for {cfg.n_trackers} trackers at {cfg.control_rate:g} Hz, '
                f"{latency * 1e3:g} ms (the configuration's are predicted to lose the "
                'formation; --gains config keeps them): '
                + ', '.join(
                    f'{k} = {v:.4g}' if isinstance(v, float) else f'{k} = {v}'
                    for k, v in gains.items()
                )
            )
            self.gains_scheduled = gains
        for w in warnings:
            self.say(f'warning: {w}')
        if not pred.holds and self.plan.gains == 'auto':
            self._say_largest(base, latency, machine)
        self.cfg = cfg
        self.prediction = pred
        return cfg

    def _say_largest(self, cfg: SwarmConfig, latency: float, machine: Any) -> None:
        """No gains hold the run: say so, with the largest swarm predicted to hold at its rate
        here (``cfg``: before gains were scheduled)."""
        from apf_swarm_core.sampled import largest_holding

        from ..capacity import probe

        rate = cfg.control_rate
        given = cfg.latency or machine is None

        def latency_of(m: int) -> float:
            if given:
                return latency
            k = self.plan.trackers_per_process or probe.trackers_per_process(machine, m, rate)
            return float(probe.derive(machine, m, rate, k)['latency'])

        found = largest_holding(cfg, latency_of)
        head = (
            f'warning: no gains are predicted to hold {cfg.n_trackers} trackers at {rate:g} '
            f'Hz with {latency * 1e3:.4g} ms of latency: '
        )
        if found is None:
            self.say(head + 'fly fewer trackers, or at another rate')
            return
        most, pred, gains = found
        sets = ''.join(
            f' --set {k}={v:.4g}' if isinstance(v, float) else f' --set {k}={v}'
            for k, v in gains.items()
        )
        self.say(
            head + f'of smaller swarms (in steps of {cfg.n_trackers / 8:g}), the largest whose '
            f'loop is predicted to hold at {rate:g} Hz is {most} trackers '
            f'({pred.latency * 1e3:.4g} ms); its {pred.settling()}: whether it flies in '
            f'{cfg.duration:g} s, `apf-swarm '
            f'simulate` with this configuration and `--n-trackers {most} --control-rate '
            f'{rate:g} --latency {pred.latency:.3g} --duration {cfg.duration:g}{sets}` says'
        )

    def judged(self, traj: dict[str, Any]) -> dict[str, Any]:
        """The run judged by flight beside its headless emulation with the latencies the
        plant measured, and the prediction before it."""
        import numpy as np
        from apf_swarm_core.command_hold import answers
        from apf_swarm_core.formation import design_pair_sets
        from apf_swarm_core.metrics import flight
        from apf_swarm_core.simulator import simulate

        assert self.cfg is not None  # check() ran before the run
        pairs = design_pair_sets(self.cfg)
        # the run's delays in their order (drawn independently they would average out)
        held = np.asarray(traj.get('command_latency', np.zeros((0, 0))), dtype=float)
        seq = answers(traj['t'], held) if held.size else held
        lat = seq[np.isfinite(seq)]
        out: dict[str, Any] = {
            'before_run': self.prediction.to_dict(),
            'gains_scheduled': self.gains_scheduled,
            'machine': self.capacity,
            'run': flight(traj, pairs),
        }
        if lat.size:
            out['latency'] = {
                q: round(float(np.quantile(lat, v)), 6)
                for q, v in (('p50', 0.5), ('p90', 0.9), ('p99', 0.99))
            }
            emu_cfg = self.cfg.replace(
                duration=float(traj['t'][-1] - traj['t'][0]) or self.cfg.duration,
                latency=float(np.median(lat)),
            )
            emu = simulate(
                emu_cfg,
                latency_samples=seq,
                stale_after=self.plan.stale_after,  # zeroed as late as the plant does
            )
            out['emulation'] = flight(emu.trajectory, pairs)
            out['latency_samples'] = np.round(lat[:: max(1, lat.size // 2000)], 6).tolist()
        return out
