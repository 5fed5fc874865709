"""Colours shared by the live view and the animations: a UAV by its state, the target,
and a formation edge by its error against the design."""

from __future__ import annotations

__all__ = ['EDGE_BAD', 'EDGE_GOOD', 'STATE_COLOURS', 'TARGET_COLOUR', 'edge_colour']

#: RGBA of a UAV by its state
STATE_COLOURS: dict[str, tuple[float, float, float, float]] = {
    'active': (0.15, 0.75, 0.3, 1.0),
    'stale': (1.0, 0.6, 0.0, 1.0),
    'inactive': (0.5, 0.5, 0.5, 0.6),
    'respawned': (0.3, 0.5, 1.0, 1.0),
}
TARGET_COLOUR = (0.9, 0.15, 0.15, 1.0)
#: an edge within EDGE_GOOD of its design distance (relative) is green, past EDGE_BAD red
EDGE_GOOD, EDGE_BAD = 0.02, 0.2


def edge_colour(rel_error: float) -> tuple[float, float, float, float]:
    """Green at ``|rel_error| <= EDGE_GOOD``, through yellow, to red at ``>= EDGE_BAD``."""
    f = min(1.0, max(0.0, (abs(rel_error) - EDGE_GOOD) / (EDGE_BAD - EDGE_GOOD)))
    return (min(1.0, 2.0 * f), min(1.0, 2.0 * (1.0 - f)), 0.1, 1.0)
