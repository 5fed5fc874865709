"""Figures matching the paper's Figures 1-7, and the sweep trade-off plot (matplotlib, PNG).

Inputs are trajectory dicts of the ``trajectory.npz`` schema (``t``, ``x``, ``target_x``, ...),
so the same functions draw a simulator run and a recorded bag.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt
import matplotlib.ticker
import numpy as np
from apf_swarm_core.metrics import centroid_error
from matplotlib.figure import Figure

__all__ = [
    'paper_figures',
    'plot_centroid',
    'plot_centroid_error',
    'plot_tradeoff',
    'plot_trajectories_3d',
    'plot_xy_time',
    'save_figure',
]

Traj = Mapping[str, Any]
_LAW_TITLE = {'traditional': 'traditional (sign) law', 'proposed': 'proposed (saturated) law'}


def save_figure(fig: Figure, path: Path) -> Path:
    """``fig`` laid out and written to ``path`` (PNG at the figures' dpi), then closed."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_trajectories_3d(traj: Traj, title: str, path: Path) -> Path:
    """Figures 1 / 2: 3-D trajectories of the trackers and the target."""
    fig = plt.figure(figsize=(6.4, 5.2))
    ax = fig.add_subplot(projection='3d')
    x, tx = np.asarray(traj['x']), np.asarray(traj['target_x'])
    for i in range(x.shape[1]):
        ax.plot(x[:, i, 0], x[:, i, 1], x[:, i, 2], lw=0.8, label=f'UAV {i + 1}')
    ax.plot(tx[:, 0], tx[:, 1], tx[:, 2], 'k--', lw=1.2, label='target')
    ax.scatter(*x[-1].T, s=12, c='C3')
    ax.scatter(*tx[-1], s=25, c='k', marker='*')
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    ax.set_zlabel('z [m]')
    ax.set_title(title)
    if x.shape[1] <= 10:
        ax.legend(fontsize=7, loc='upper left')
    return save_figure(fig, path)


def plot_xy_time(traj: Traj, title: str, path: Path) -> Path:
    """Figures 3 / 4: x and y of every tracker and the target against time."""
    t, x, tx = np.asarray(traj['t']), np.asarray(traj['x']), np.asarray(traj['target_x'])
    fig, axes = plt.subplots(2, 1, figsize=(6.4, 5.2), sharex=True)
    for k, ax in enumerate(axes):
        for i in range(x.shape[1]):
            ax.plot(t, x[:, i, k], lw=0.8, label=f'UAV {i + 1}')
        ax.plot(t, tx[:, k], 'k--', lw=1.0, label='target')
        ax.set_ylabel('xy'[k] + ' [m]')
        ax.grid(alpha=0.3)
    axes[0].set_title(title)
    axes[-1].set_xlabel('t [s]')
    if x.shape[1] <= 10:
        axes[0].legend(fontsize=7, ncol=2)
    return save_figure(fig, path)


def plot_centroid(traj: Traj, title: str, path: Path) -> Path:
    """Figures 5 / 6: the formation's geometric centre against the target (x-y plane)."""
    x, tx = np.asarray(traj['x']), np.asarray(traj['target_x'])
    cen = x.mean(axis=1)
    fig, ax = plt.subplots(figsize=(6.0, 5.2))
    ax.plot(tx[:, 0], tx[:, 1], 'k--', lw=1.2, label='target')
    ax.plot(cen[:, 0], cen[:, 1], 'C1', lw=0.9, label='formation centre')
    ax.set_xlabel('x [m]')
    ax.set_ylabel('y [m]')
    ax.set_aspect('equal', adjustable='datalim')
    ax.grid(alpha=0.3)
    ax.legend()
    ax.set_title(title)
    return save_figure(fig, path)


def plot_centroid_error(trajs: Mapping[str, Traj], title: str, path: Path) -> Path:
    """Figure 7: centroid-to-target error of several laws on one axes (log scale)."""
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for label, traj in trajs.items():
        err = centroid_error(traj['x'], traj['target_x'])
        ax.semilogy(
            np.asarray(traj['t']),
            np.maximum(err, 1e-6),
            lw=0.9,
            label=_LAW_TITLE.get(label, label),
        )
    ax.set_xlabel('t [s]')
    ax.set_ylabel('|centroid - target| [m]')
    ax.grid(alpha=0.3, which='both')
    ax.legend()
    ax.set_title(title)
    return save_figure(fig, path)


def paper_figures(trajs: Mapping[str, Traj], out: Path, prefix: str = '') -> list[Path]:
    """All of Figures 1-7 for ``{'traditional': traj, 'proposed': traj}`` into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    numbers = {'traditional': (1, 3, 5), 'proposed': (2, 4, 6)}
    figures = (
        (plot_trajectories_3d, 'trajectories', 'trajectories'),
        (plot_xy_time, 'x and y', 'xy'),
        (plot_centroid, 'formation centre', 'centroid'),
    )
    for law, traj in trajs.items():
        name = _LAW_TITLE.get(law, law)
        for (plot, what, stem), number in zip(figures, numbers.get(law, (0, 0, 0)), strict=True):
            title = f'Fig. {number}: {what}, {name}'
            paths.append(plot(traj, title, out / f'{prefix}fig{number}_{stem}_{law}.png'))
    paths.append(
        plot_centroid_error(
            trajs, 'Fig. 7: centroid error', out / f'{prefix}fig7_centroid_error.png'
        )
    )
    return paths


def plot_tradeoff(rows: Sequence[Mapping[str, Any]], param: str, path: Path) -> Path:
    """Chattering against tracking error for every law and parameter value of a sweep.

    ``rows`` have keys ``law``, ``value``, ``centroid_rms``, ``hf_velocity_rms`` and
    ``heading_rate`` (one row per run; seeds are averaged here).
    """
    fig, axes = plt.subplots(1, 2, figsize=(10.0, 4.2))
    for law, marker in (('proposed', 'o'), ('traditional', 's')):
        sel = [r for r in rows if r['law'] == law]
        values = sorted({r['value'] for r in sel}, key=lambda v: (isinstance(v, str), v))
        for ax, key, label in (
            (axes[0], 'hf_velocity_rms', 'HF velocity RMS [m/s]'),
            (axes[1], 'heading_rate', 'heading rate [rad/s]'),
        ):
            xs = [np.mean([r['centroid_rms'] for r in sel if r['value'] == v]) for v in values]
            ys = [np.mean([r[key] for r in sel if r['value'] == v]) for v in values]
            ax.plot(xs, ys, marker=marker, lw=1.0, label=_LAW_TITLE[law])
            if len({(round(a, 12), round(b, 12)) for a, b in zip(xs, ys, strict=False)}) == 1:
                continue  # the parameter does not change this law: one point, no labels
            for xv, yv, v in zip(xs, ys, values, strict=False):
                ax.annotate(
                    f'{param}={v:g}' if isinstance(v, float) else f'{param}={v}',
                    (xv, yv),
                    fontsize=6,
                    textcoords='offset points',
                    xytext=(3, 3),
                )
            ax.set_xlabel('steady centroid error RMS [m]')
            ax.set_ylabel(label)
            ax.set_xscale('log')
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
            ax.grid(alpha=0.3, which='both')
    axes[0].legend()
    fig.suptitle(f'chattering against tracking error over {param}')
    return save_figure(fig, path)
