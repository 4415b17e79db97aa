"""The figures of one run (the paper's Figs. 3-7), drawn with Matplotlib alone.

``run`` and ``reproduce`` draw these. They use Matplotlib's bundled seaborn
style sheets rather than seaborn itself: importing seaborn imports
``scipy.stats``, about a second of a command that draws three figures. The
figures of a results table are in :mod:`formation_bench.benchmarks.analysis.figures`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ParamSpec

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from formation_bench.mpc.metrics import pair_names

STYLE = ("seaborn-v0_8-whitegrid", "seaborn-v0_8-notebook", "seaborn-v0_8-deep")
"""Matplotlib style sheets of these figures: seaborn's white grid, notebook sizes, deep colours."""

_P = ParamSpec("_P")


def _styled(draw: Callable[_P, plt.Figure]) -> Callable[_P, plt.Figure]:
    """Draw under :data:`STYLE`, leaving the caller's Matplotlib settings as they were."""

    @functools.wraps(draw)
    def styled(*args: _P.args, **kwargs: _P.kwargs) -> plt.Figure:
        with plt.style.context(STYLE):
            return draw(*args, **kwargs)

    return styled


def _colours() -> list[str]:
    """The colour cycle of the current style."""
    return list(plt.rcParams["axes.prop_cycle"].by_key()["color"])


def wide(frame: pd.DataFrame, column: str) -> pd.DataFrame:
    """One column of the trace with a row per instant and a column per UAV."""
    return frame.pivot(index="time_s", columns="uav", values=column)


def _title(frame: pd.DataFrame, what: str) -> str:
    first = frame.iloc[0]
    trigger = "with trigger" if first["trigger"] else "without trigger"
    return f"{what}: {first['optimizer']}, {first['scenario']}, {trigger}, seed {first['seed']}"


@_styled
def trajectory_figure(frame: pd.DataFrame, snapshot_every_s: float = 8.0) -> plt.Figure:
    """Figs. 3 and 5: UAV paths, the reference path, and the formation at intervals."""
    fig, ax = plt.subplots(figsize=(8, 6), constrained_layout=True)
    palette = _colours()[: frame["uav"].nunique()]
    reference = frame[frame["uav"] == frame["uav"].min()]
    ax.plot(reference["ref_x_m"], reference["ref_y_m"], "k--", lw=1.2, label="reference centre")
    for colour, (uav, rows) in zip(palette, frame.groupby("uav"), strict=True):
        ax.plot(rows["x_m"], rows["y_m"], color=colour, lw=1.5, label=f"UAV {uav}")
        ax.plot(rows["x_m"].iloc[0], rows["y_m"].iloc[0], "o", color=colour, ms=6)
    x, y = wide(frame, "x_m"), wide(frame, "y_m")
    times = x.index.to_numpy()
    for t in np.arange(0.0, times[-1] + 1e-9, snapshot_every_s):
        row = int(np.argmin(np.abs(times - t)))
        px, py = x.iloc[row].to_numpy(), y.iloc[row].to_numpy()
        ax.fill(px, py, facecolor="none", edgecolor="0.4", lw=0.8)
        centre_x, centre_y = px.mean(), py.mean()
        ax.plot(centre_x, centre_y, "x", color="0.3", ms=5)
    ax.plot([], [], color="0.4", lw=0.8, label=f"formation every {snapshot_every_s:g} s")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="best", fontsize=9)
    ax.set_title(_title(frame, "Trajectories"), fontsize=10)
    return fig


@_styled
def states_figure(
    frame: pd.DataFrame, desired_distances: dict[str, float], settle_time_s: float
) -> plt.Figure:
    """Figs. 4 and 6: states, controls, pairwise distances and tracking error over time."""
    fig, axes = plt.subplots(3, 2, figsize=(11, 9), sharex=True, constrained_layout=True)
    panels = [
        ("speed_m_s", "speed v (m/s)", 1.0),
        ("heading_rad", "heading θ (deg)", 180.0 / np.pi),
        ("accel_m_s2", "acceleration a (m/s²)", 1.0),
        ("turn_rate_rad_s", "turn rate ω (rad/s)", 1.0),
    ]
    for ax, (column, label, scale) in zip(axes.flat[:4], panels, strict=True):
        values = wide(frame, column) * scale
        for uav in values.columns:
            drawstyle = "steps-post" if column in ("accel_m_s2", "turn_rate_rad_s") else "default"
            ax.plot(values.index, values[uav], lw=1.2, label=f"UAV {uav}", drawstyle=drawstyle)
        ax.set_ylabel(label)
    axes[0, 0].legend(fontsize=8)
    x, y = wide(frame, "x_m"), wide(frame, "y_m")
    ax = axes[2, 0]
    n_uav = x.shape[1]
    for name, i, j in pair_names(n_uav):
        distance = np.hypot(x.iloc[:, i] - x.iloc[:, j], y.iloc[:, i] - y.iloc[:, j])
        (line,) = ax.plot(x.index, distance, lw=1.2, label=name)
        ax.axhline(desired_distances[name], color=line.get_color(), ls=":", lw=1)
    ax.set_ylabel("pairwise distance (m)")
    ax.set_xlabel("time (s)")
    ax.legend(fontsize=8, title="dotted: desired", title_fontsize=8)
    ax = axes[2, 1]
    reference = frame[frame["uav"] == frame["uav"].min()].set_index("time_s")
    error = np.hypot(x.mean(axis=1) - reference["ref_x_m"], y.mean(axis=1) - reference["ref_y_m"])
    ax.plot(error.index, error, color="k", lw=1.2)
    ax.axvline(settle_time_s, color="0.5", ls="--", lw=1, label=f"settle time {settle_time_s:g} s")
    ax.set_yscale("log")
    ax.set_ylabel("centre tracking error (m)")
    ax.set_xlabel("time (s)")
    ax.legend(fontsize=8)
    fig.suptitle(_title(frame, "States and distances"), fontsize=10)
    return fig


@_styled
def trigger_figure(frame: pd.DataFrame) -> plt.Figure:
    """Fig. 7: the instants at which each UAV re-solved."""
    fig, ax = plt.subplots(figsize=(10, 3.2), constrained_layout=True)
    colours = _colours()
    uavs = sorted(frame["uav"].unique())
    n_instants = frame.loc[frame["uav"] == uavs[0], "step"].max()
    for row, uav in enumerate(uavs):
        times = frame.loc[(frame["uav"] == uav) & frame["solved"], "time_s"].to_numpy()
        ax.vlines(times, row + 0.6, row + 1.4, lw=1.2, color=colours[row % len(colours)])
        ax.text(
            1.005,
            row + 1,
            f"{times.size}/{n_instants}",
            transform=ax.get_yaxis_transform(),
            va="center",
            fontsize=9,
        )
    ax.set_yticks(range(1, len(uavs) + 1), [f"UAV {u}" for u in uavs])
    ax.set_ylim(0.4, len(uavs) + 0.6)
    ax.set_xlabel("time (s)")
    ax.set_title(_title(frame, "Solve instants (count / update instants)"), fontsize=10)
    return fig


def save(fig: plt.Figure, path) -> None:
    """Save as PNG at a legible resolution and free the figure."""
    fig.savefig(path, dpi=120)
    plt.close(fig)
