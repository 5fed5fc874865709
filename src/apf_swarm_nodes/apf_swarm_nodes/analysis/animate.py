"""Animations of a run (matplotlib ``FuncAnimation``): the swarm in 3-D or from above, with
the target, the formation's edges coloured by their error against the design, short trails
and the time; GIF through Pillow, MP4 through ffmpeg.

Input is a trajectory dict of the ``trajectory.npz`` schema (``t``, ``x``, ``target_x``,
optionally ``active``), so the same function animates a simulator run and a recorded bag.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use('Agg')
import numpy as np
from numpy.typing import NDArray

from .errors import AnalysisError
from .style import STATE_COLOURS, TARGET_COLOUR, edge_colour

__all__ = ['FORMATS', 'animate', 'auto_speed', 'check_path', 'frame_indices']

#: file suffix -> matplotlib writer
FORMATS = {'.gif': 'pillow', '.mp4': 'ffmpeg'}
TRAIL = 3.0  # [s of run time]


def frame_indices(t: NDArray[np.float64], speed: float, fps: int) -> NDArray[np.intp]:
    """The sample shown in each frame: frame f shows the run at ``t_0 + f speed / fps``
    (the last sample at or before it), up to the end of the run."""
    t = np.asarray(t, dtype=float)
    if len(t) == 0:
        return np.zeros(0, dtype=np.intp)
    # a frame time that equals a sample's time up to rounding shows that sample
    eps = 1e-9 * max(1.0, float(np.abs(t).max()))
    frames = int(np.floor((t[-1] - t[0]) * fps / speed + eps)) + 1
    times = t[0] + np.arange(frames) * speed / fps + eps
    return np.clip(np.searchsorted(t, times, side='right') - 1, 0, len(t) - 1)


def auto_speed(duration: float, longest: float = 20.0) -> float:
    """The speed-up that shows a run of ``duration`` seconds in at most ``longest`` seconds
    (real time for a short run)."""
    return max(1.0, float(duration) / longest)


def check_path(path: Path) -> str:
    """The matplotlib writer for ``path``'s suffix; AnalysisError for an unknown format or an MP4
    without ffmpeg (checked before a run, so that nothing is computed for nothing)."""
    kind = FORMATS.get(path.suffix.lower())
    if kind is None:
        raise AnalysisError(
            f'{path}: unknown animation format {path.suffix!r}; use a .gif or .mp4 file name'
        )
    if kind == 'ffmpeg' and (
        shutil.which(str(matplotlib.rcParams['animation.ffmpeg_path'])) is None
    ):
        raise AnalysisError(
            f'{path}: writing MP4 needs ffmpeg, which is not installed here (apt-get install '
            'ffmpeg); or write a GIF (FILE.gif)'
        )
    return kind


def _writer(path: Path, fps: int) -> Any:
    from matplotlib import animation

    if check_path(path) == 'pillow':
        return animation.PillowWriter(fps=fps)
    return animation.FFMpegWriter(fps=fps, codec='libx264', extra_args=['-pix_fmt', 'yuv420p'])


def animate(
    traj: Mapping[str, Any],
    path: Path,
    *,
    designs: Sequence[NDArray[np.float64]] = (),
    speed: float = 1.0,
    fps: int = 15,
    view: str = '3d',
    title: str = '',
    size: tuple[float, float] = (6.4, 4.8),
    dpi: int = 80,
    progress: Callable[[int, int], None] | None = None,
) -> int:
    """Write the animation of ``traj`` to ``path`` (.gif or .mp4) at ``speed`` times real
    time and ``fps`` frames per second; ``view``: ``3d`` or ``top``; returns the frames."""
    import matplotlib.pyplot as plt
    from apf_swarm_core.metrics import formation_edges, nearest_design
    from matplotlib import animation

    if view not in ('3d', 'top'):
        raise AnalysisError(f'--projection {view!r}: expected 3d or top')
    writer = _writer(path, fps)
    t = np.asarray(traj['t'], dtype=float)
    x = np.asarray(traj['x'], dtype=float)
    tx = np.asarray(traj['target_x'], dtype=float)
    if len(t) < 2:
        raise AnalysisError(f'{len(t)} sample: an animation needs two')
    active = np.asarray(traj.get('active', np.ones(x.shape[:2], dtype=bool)), dtype=bool)
    idx = frame_indices(t, speed, fps)
    n = x.shape[1]
    pts = np.concatenate([x.reshape(-1, 3), tx])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1.0) * 1.05
    fig = plt.figure(figsize=size, dpi=dpi)
    ax: Any = fig.add_subplot(projection='3d') if view == '3d' else fig.add_subplot()
    dims = 3 if view == '3d' else 2
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    ax.set_title(title)
    if view == '3d':
        ax.set_zlim(centre[2] - half, centre[2] + half)
        ax.set_zlabel('z [m]')
        stamp = ax.text2D(0.02, 0.95, '', transform=ax.transAxes)
    else:
        ax.set_aspect('equal')
        stamp = ax.text(0.02, 0.95, '', transform=ax.transAxes)
    lines: list[Any] = []
    design_list = list(designs)

    def xyz(p: NDArray[np.float64]) -> list[Any]:
        return [p[..., k] for k in range(dims)]

    def draw(f: int) -> list[Any]:
        i = int(idx[f])
        for artist in lines:
            artist.remove()
        lines.clear()
        first = int(np.searchsorted(t, t[i] - TRAIL))
        for j in range(n):
            c = STATE_COLOURS['active' if active[i, j] else 'inactive']
            lines.extend(ax.plot(*xyz(x[first : i + 1, j]), color=c, alpha=0.4, lw=1))
            lines.extend(ax.plot(*xyz(x[i, j][None]), 'o', color=c, ms=7))
        lines.extend(ax.plot(*xyz(tx[i][None]), '*', color=TARGET_COLOUR, ms=12))
        design = nearest_design(x[i][None], design_list) if design_list else None
        if design is not None and len(design) == n * (n - 1) // 2:
            a, b, dd, err = formation_edges(x[i], design)
            for p, q, d, e in zip(a, b, dd, err, strict=True):
                seg = np.stack([x[i, p], x[i, q]])
                lines.extend(ax.plot(*xyz(seg), color=edge_colour(float(e / d)), lw=1.5))
        stamp.set_text(f't = {t[i]:6.2f} s  ({speed:g}x)')
        if progress is not None:
            progress(f + 1, len(idx))
        return [*lines, stamp]

    anim = animation.FuncAnimation(fig, draw, frames=len(idx), blit=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        anim.save(str(path), writer=writer, dpi=dpi)
    finally:
        plt.close(fig)
    return len(idx)
