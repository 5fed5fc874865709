"""Which of the paper's conditions hold for a configuration, each a :class:`Finding`:
``beta >= v_N`` (eq. 10-11), the formation's existence, the u0 bounds of eq. 29, 37 and 43
(:mod:`apf_swarm_core.gain_bounds`) and the numerics of docs/THEORY.md section 2 (the filter
against dt, the ripple ``u0 T / M``, the boundary-layer lag)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Literal

from .advice import PLAIN, Advice
from .config import SwarmConfig
from .design import expected_spacing, triangle_spacing
from .gain_bounds import GainBound, gain_bounds, gain_bounds_from_run

__all__ = ['CheckReport', 'Finding', 'check_config', 'sampled_findings']

Level = Literal['ok', 'info', 'warning', 'error']


@dataclass(frozen=True)
class Finding:
    """One condition and its verdict."""

    level: Level
    code: str
    message: str


@dataclass
class CheckReport:
    """All findings and gain bounds for one configuration."""

    findings: list[Finding] = field(default_factory=list)
    bounds: list[GainBound] = field(default_factory=list)
    estimates: dict[str, float] = field(default_factory=dict)

    @property
    def exit_code(self) -> int:
        """0 consistent, 1 warnings only, 2 errors."""
        levels = {f.level for f in self.findings}
        return 2 if 'error' in levels else 1 if 'warning' in levels else 0

    @property
    def warnings(self) -> list[str]:
        return [f.message for f in self.findings if f.level in ('warning', 'error')]

    def as_dict(self) -> dict[str, Any]:
        return {
            'exit_code': self.exit_code,
            'findings': [f.__dict__ for f in self.findings],
            'bounds': [b.as_dict() for b in self.bounds],
            'estimates': self.estimates,
        }


def _bound_findings(
    cfg: SwarmConfig, bounds: list[GainBound], source: str, fail_level: Level
) -> list[Finding]:
    out = []
    for bnd in bounds:
        if cfg.law == 'traditional' and bnd.name == 'eq43':
            continue
        code = f'u0_{bnd.name}_{"measured" if source.startswith("measured") else "a_priori"}'
        level: Level = 'ok' if bnd.holds_corrected else fail_level
        if bnd.holds_corrected:
            msg = (
                f'> {bnd.corrected:.4g}, the corrected {bnd.name} bound ({bnd.regime}; printed '
                f'form {bnd.printed:.4g}).'
            )
        elif bnd.holds_printed:
            msg = (
                f'clears the printed {bnd.name} bound {bnd.printed:.4g} but not the corrected '
                f'one {bnd.corrected:.4g} ({bnd.regime}): reaching the manifold is not '
                'guaranteed against the worst-case disturbance.'
            )
        else:
            msg = (
                f'is below both the printed ({bnd.printed:.4g}) and the corrected '
                f'({bnd.corrected:.4g}) {bnd.name} bound ({bnd.regime}).'
            )
        out.append(Finding(level, code, f'{source}: u0 = {cfg.u0:g} {msg}'))
    return out


def sampled_findings(
    cfg: SwarmConfig, run: dict[str, Any] | None = None, advice: Advice = PLAIN
) -> list[Finding]:
    """:func:`apf_swarm_core.sampled.predict` at ``cfg.control_rate`` and ``cfg.latency`` in
    words (its warnings as warnings), and whether ``run``, the emulation there, flew
    (:func:`apf_swarm_core.metrics.flight`)."""
    from .formation import design_pair_sets
    from .metrics import flight
    from .sampled import predict

    pred = predict(cfg, advice=advice)
    T = pred.control_period
    summary = (
        f'real time at {1 / T:g} Hz (T = {T * 1e3:g} ms) with {pred.latency * 1e3:g} ms '
        f'latency, {cfg.switching} switching: formation loop rate K lambda_max = '
        f'{pred.layer_gain:.4g} x {pred.hessian_max:.4g} = {pred.formation_rate:.4g} 1/s '
        f'against {pred.rate_allowed:.4g} 1/s allowed; ripple u0 T / M = {pred.ripple:.3g} '
        f'm/s; steady lag {pred.steady_lag:.3g} m; {pred.settling()}; predicted to '
        f'{"hold" if pred.holds else "fail"}.'
    )
    out = [Finding('info', 'sampled', summary)]
    out += [Finding('warning', 'sampled', w) for w in pred.warnings]
    if run is not None:
        f = flight(run, design_pair_sets(cfg))
        if f['formation_error_rms'] is not None:
            # what the emulation says outranks the linear prediction: a run that does not
            # fly there is a warning, whatever the prediction held
            flies = f['flies']
            msg = (
                f'the emulation at this rate and latency {"flies" if flies else "does not fly"}: '
                f'formation error RMS {100 * f["formation_error_rms"]:.2g} % of the mean design '
                f"spacing, closest pair {100 * f['closest_pair']:.3g} % of the design's, "
                f'centroid error RMS {f["centroid_error_rms"]:.3g} m over the last '
                f'{100 * f["window"]:g} %'
            )
            if not flies:
                redesign = advice.redesign(1.0 / T, pred.latency, cfg.n_trackers)
                msg += f'; fly fewer trackers or at a higher rate, or {redesign}'
            out.append(Finding('info' if flies else 'warning', 'emulation', msg + '.'))
    return out


#: a start whose closest pair is below this fraction of the formation's spacing is warned of
START_CLOSE = 0.1


def _start_finding(cfg: SwarmConfig, spacing: float) -> tuple[Level, str, str]:
    """How close the start puts two trackers, against the formation's ``spacing`` [m]."""
    from scipy.spatial.distance import pdist

    from .simulator import initial_positions

    closest = float(pdist(initial_positions(cfg)).min())
    if closest >= START_CLOSE * spacing:
        return 'ok', 'start', f'the closest two trackers start {closest:.3g} m apart.'
    why = (
        f'the closest two trackers start {closest:.3g} m apart, {closest / spacing:.0%} of '
        f'the formation spacing {spacing:.3g} m: vehicles of that size would collide before '
        'the swarm spreads. Set init_separation (e.g. 0.5 m: no two start closer; the ball '
        'grows to hold them).'
    )
    return 'warning', 'start', why


def check_config(
    cfg: SwarmConfig,
    run: dict[str, Any] | None = None,
    *,
    realtime: bool = False,
    advice: Advice = PLAIN,
) -> CheckReport:
    """Every condition for ``cfg``, in words: what holds, what fails, and what will happen.

    ``run`` (a trajectory with ``t``, ``x``, ``target_x``) adds the u0 bounds measured on it,
    the only ones that can warn (the a priori ones are far too conservative). ``realtime``:
    also :func:`sampled_findings` (``run`` is then the emulation at that rate). ``advice``:
    the words of the remedies the warnings propose.
    """
    rep = CheckReport()

    def add(level: Level, code: str, message: str) -> None:
        rep.findings.append(Finding(level, code, message))

    vn = cfg.target_speed_bound
    if cfg.beta >= vn:
        msg = f'beta = {cfg.beta:g} >= v_N = {vn:g}: the convergence condition of eq. 10-11 holds.'
        add('ok', 'beta_vs_vn', msg)
    else:
        add(
            'warning',
            'beta_vs_vn',
            f'beta = {cfg.beta:g} < v_N = {vn:g}: the convergence proof (eq. 10-11) does '
            'not apply. The switching term cannot keep up with the target: the trackers '
            f'trail it until alpha |grad J| makes up the missing {vn - cfg.beta:g} m/s '
            f'(about {(vn - cfg.beta) / max(cfg.alpha, 1e-12) / cfg.k_n:.3g} m behind for '
            'a straight target). Raise beta to at least v_N.',
        )
    # formation existence
    n, d = cfg.n_trackers, None
    level: Level
    if n < 2:
        level, msg = 'info', 'one tracker: no formation, it converges onto the target.'
    elif n == 3:
        d = triangle_spacing(cfg.a, cfg.b, cfg.c, cfg.k_n, cfg.k_f)
        thr = cfg.a + cfg.k_n / (3 * cfg.k_f)
        if d is not None:
            level, msg = 'ok', f'the triangle exists with side d = {d:.4g} m '
            msg += f'(b = {cfg.b:g} > a + k_n/(3 k_f) = {thr:g}).'
        else:
            level = 'warning'
            msg = f'b = {cfg.b:g} <= a + k_n/(3 k_f) = {thr:g}: no triangle exists. ' + (
                'With b < a the pair term never repels, so '
                if cfg.b < cfg.a
                else 'The repulsion is too weak to balance the target attraction, so '
            )
            msg += 'the trackers collapse onto the target and onto each other. Choose '
            msg += f'b > {thr:g} ({advice.spacing()}).'
    elif cfg.b <= cfg.a:
        level = 'warning'
        msg = f'b = {cfg.b:g} <= a = {cfg.a:g}: the pair term never repels; the trackers '
        msg += 'collapse onto each other.'
    elif (d := expected_spacing(n, **cfg.potential_params())) is not None:
        level = 'ok'
        msg = f'the equilibrium formation of {n} trackers has nearest-neighbour spacing {d:.4g} m.'
    else:
        level = 'warning'
        msg = f'no formation of {n} trackers: the equilibrium of J collapses; raise b.'
    add(level, 'formation', msg)
    if d is not None:
        add(*_start_finding(cfg, d))
    # gain bounds: a priori (conservative, informative only) and measured on a run
    bounds, est = gain_bounds(cfg)
    rep.bounds, rep.estimates = bounds, {f'a_priori_{k}': v for k, v in est.items()}
    rep.findings += _bound_findings(cfg, bounds, 'a priori estimate (conservative)', 'info')
    if run is not None:
        mbounds, mest = gain_bounds_from_run(cfg, run['t'], run['x'], run['target_x'])
        rep.bounds += [replace(b, name=b.name + '_measured') for b in mbounds]
        rep.estimates.update({f'measured_{k}': v for k, v in mest.items()})
        rep.findings += _bound_findings(
            cfg, mbounds, 'measured on a run (steady window)', 'warning'
        )
    # numerics
    if cfg.dt > cfg.lambda_filter / 10:
        add(
            'warning',
            'filter_dt',
            f'dt = {cfg.dt:g} s is not small against lambda_filter = {cfg.lambda_filter:g} s: '
            'the filter of eq. 26 cannot average the switching; use dt <= lambda_filter / 10.',
        )
    m_lo = min(min(r) for r in cfg.mass_matrix_diag())
    ripple = cfg.u0 * cfg.control_period / m_lo
    add(
        'info',
        'ripple',
        f'switching ripple of the velocity about u0 T / M = {ripple:.3g} m/s per control '
        f'period T = {cfg.control_period:g} s (docs/THEORY.md): it scales with the period.',
    )
    if cfg.law == 'proposed' and cfg.beta >= vn:
        w = cfg.feedforward  # the lag of sampled.predict, at any rate
        lag = (1.0 - w) * vn / (cfg.k_n * (cfg.alpha + cfg.beta / cfg.gamma))
        add(
            'info',
            'lag',
            f'inside the boundary layer the law is linear with gain '
            f'alpha + beta/gamma = {cfg.alpha + cfg.beta / cfg.gamma:.4g} 1/s: a target '
            f'at {vn:g} m/s is trailed by about (1 - w) v_N / (k_n (alpha + beta/gamma)) = '
            f'{lag:.3g} m with the feed-forward w = {w:g} (smaller gamma: less lag, more '
            'switching).',
        )
    if realtime:
        rep.findings += sampled_findings(cfg, run, advice)
    return rep
