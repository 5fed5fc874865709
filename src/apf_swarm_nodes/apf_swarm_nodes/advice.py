"""The command line's words for the remedies the core proposes: the ``apf-swarm design``
command that computes them (:class:`apf_swarm_core.advice.Advice`)."""

from __future__ import annotations

from apf_swarm_core.advice import Advice

__all__ = ['CLI_ADVICE', 'CliAdvice']


class CliAdvice(Advice):
    """Each remedy as the ``apf-swarm design`` command line that computes it."""

    def redesign(self, control_rate: float, latency: float, n_trackers: int | None = None) -> str:
        size = f' --n-trackers {n_trackers}' if n_trackers is not None else ''
        return (
            f'run `apf-swarm design --control-rate {control_rate:g} --latency {latency:g}{size}`'
        )

    def spacing(self) -> str:
        return 'apf-swarm design --spacing D gives b for a spacing D'


CLI_ADVICE = CliAdvice()
