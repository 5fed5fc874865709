"""How a warning words the remedy it proposes. The core's words name functions and values,
never a command: a front end that has a command for the remedy passes an :class:`Advice` of
its own (the command line's is :data:`apf_swarm_nodes.advice.CLI_ADVICE`)."""

from __future__ import annotations

__all__ = ['PLAIN', 'Advice']


class Advice:
    """The remedies the checks and the sampled-data prediction propose, in the core's words."""

    def redesign(self, control_rate: float, latency: float, n_trackers: int | None = None) -> str:
        """Gains designed for ``control_rate`` [Hz] and ``latency`` [s] (and a size)."""
        size = f' and {n_trackers} trackers' if n_trackers is not None else ''
        return (
            f'design the gains for {control_rate:g} Hz, {latency:g} s latency{size} '
            '(apf_swarm_core.sampled.propose_gains)'
        )

    def spacing(self) -> str:
        """The b of a spacing D."""
        return 'apf_swarm_core.design.triangle_b_for_spacing gives b for a spacing D'


#: the core's own words (the default of every function that warns)
PLAIN = Advice()
