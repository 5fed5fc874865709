"""The formation a configuration designs: the equilibria of J for its number of trackers and
its potential, and the pair distances a run's formation is judged against.

A thin layer over :mod:`apf_swarm_core.design`, which works from plain numbers; a run's
summary, its flight judgement, the plant's formation error and the sampled-data prediction
all ask here.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .config import SwarmConfig
from .design import Formation, design_pairs
from .design import design_formations as _design_formations

__all__ = ['design_formation', 'design_formations', 'design_pair_sets', 'expected_pairs']


def expected_pairs(cfg: SwarmConfig) -> NDArray[np.float64] | None:
    """Design pair distances of ``cfg``'s size and potential for the formation metrics
    (:func:`~apf_swarm_core.design.design_pairs`), or ``None`` when J has no formation."""
    return design_pairs(cfg.n_trackers, **cfg.potential_params())


def design_formation(cfg: SwarmConfig) -> Formation:
    """The lowest equilibrium formation of ``cfg``'s size and potential
    (:func:`~apf_swarm_core.design.design_formations`): a run's summary, its flight
    judgement, its emulation and the sampled-data prediction all ask for it."""
    return design_formations(cfg)[0]


def design_formations(cfg: SwarmConfig) -> list[Formation]:
    """Every minimum of J of ``cfg``'s size and potential that a swarm settles in, lowest
    first (:func:`~apf_swarm_core.design.design_formations`)."""
    return _design_formations(cfg.n_trackers, **cfg.potential_params())


def design_pair_sets(cfg: SwarmConfig) -> list[NDArray[np.float64]]:
    """The pair distances of every design minimum (:func:`design_formations`); for 3 and
    fewer trackers the one of :func:`expected_pairs`. Empty without a formation."""
    pairs = expected_pairs(cfg)
    if pairs is None:
        return []
    if cfg.n_trackers <= 3:
        return [pairs]
    return [f.pair_distances for f in design_formations(cfg) if f.spacing > 1e-6]
