"""The figures of one run (the paper's Figs. 3-7, and the separation figure), drawn with
Matplotlib alone.

``run`` and ``reproduce`` draw these (:func:`write_run_figures`, :func:`write_trigger_figure`).
They use Matplotlib's bundled seaborn style sheets rather than seaborn itself: importing
seaborn imports ``scipy.stats``, about a second of a command that draws three figures. The
figures of a results table are in :mod:`formation_bench.analysis.figures`.

They read the trace table (:func:`formation_bench.pipeline.outputs.trace_table`, its columns
declared in :mod:`formation_bench.pipeline.trace_columns`) of one run and, for what the table
does not hold (obstacles, the safety radius, the communication graph), its
:class:`~formation_bench.mpc.scenario.Scenario`. They draw any number of UAVs:
up to :data:`LEGEND_MAX_UAVS` each has a colour of the style and a legend entry, beyond it a
colour of :data:`UAV_COLORMAP` and a colour bar instead of the entries.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable
from pathlib import Path
from typing import ParamSpec

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.cm import ScalarMappable
from matplotlib.collections import LineCollection
from matplotlib.colors import BoundaryNorm, ListedColormap, to_hex
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Patch
from matplotlib.ticker import MaxNLocator

from formation_bench.mpc import metrics
from formation_bench.mpc.metrics import PAIR_COLUMNS_MAX_UAVS, pair_names
from formation_bench.mpc.network import listening
from formation_bench.mpc.scenario import Scenario

STYLE = ("seaborn-v0_8-whitegrid", "seaborn-v0_8-notebook", "seaborn-v0_8-deep")
"""Matplotlib style sheets of these figures: seaborn's white grid, notebook sizes, deep colours."""

LEGEND_MAX_UAVS = 6
"""Runs of up to this many UAVs (the style's colours) name every UAV in a legend."""

UAV_COLORMAP = "viridis"
"""Colormap of the UAVs of larger runs (UAV 1 dark, the last light), shown as a colour bar."""

TITLE_WIDTH = 80
"""Characters of a title line: the narrowest figure (the trajectories) holds about this many."""

OBSTACLE_COLOUR = "#8C3B3B"
"""Colour of the obstacles, their margins and the limits drawn against them."""

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


def uav_colours(n_uav: int) -> list[str]:
    """One colour per UAV: the style's colours up to :data:`LEGEND_MAX_UAVS` UAVs, else
    :data:`UAV_COLORMAP` sampled evenly (its lightest tenth left out, too pale on white)."""
    if n_uav <= LEGEND_MAX_UAVS:
        return _colours()[:n_uav]
    return [to_hex(c) for c in plt.get_cmap(UAV_COLORMAP)(np.linspace(0.0, 0.9, n_uav))]


def _uav_colour_bar(fig: plt.Figure, axes, colours: list[str]) -> None:
    """A discrete colour bar naming the UAV of each colour, beside ``axes``."""
    n_uav = len(colours)
    norm = BoundaryNorm(np.arange(0.5, n_uav + 1.0), n_uav)
    bar = fig.colorbar(
        ScalarMappable(norm=norm, cmap=ListedColormap(colours)), ax=axes, pad=0.01, aspect=30
    )
    bar.set_label("UAV")
    bar.locator = MaxNLocator(nbins=min(n_uav, 10), integer=True)
    bar.update_ticks()


def wide(frame: pd.DataFrame, column: str) -> pd.DataFrame:
    """One column of the trace with a row per instant and a column per UAV."""
    return frame.pivot(index="time_s", columns="uav", values=column)


def positions_of(frame: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """The instants ``(T + 1,)`` and every UAV's position ``(T + 1, N, 2)`` in the trace."""
    x, y = wide(frame, "x_m"), wide(frame, "y_m")
    return x.index.to_numpy(), np.stack((x.to_numpy(), y.to_numpy()), axis=-1)


def _check_scenario(frame: pd.DataFrame, scenario: Scenario) -> None:
    """A scenario of another number of UAVs than the trace is refused at once."""
    n_uav = frame["uav"].nunique()
    if scenario.n_uav != n_uav:
        raise ValueError(
            f"scenario {scenario.name!r} has {scenario.n_uav} UAVs but the trace has {n_uav}: "
            "pass the scenario of the run"
        )


def _title(frame: pd.DataFrame, what: str) -> str:
    """``what`` and the run; a label too long for one line puts the scenario (its overrides
    wrapped at commas) on lines of its own."""
    first = frame.iloc[0]
    trigger = "with trigger" if first["trigger"] else "without trigger"
    run = f"{first['optimizer']}, {trigger}, seed {first['seed']}"
    scenario = str(first["scenario"])
    text = f"{what}: {first['optimizer']}, {scenario}, {trigger}, seed {first['seed']}"
    if len(text) <= TITLE_WIDTH:
        return text
    lines = [""]
    for part in re.split(r"(?<=,)", scenario):
        if lines[-1] and len(lines[-1]) + len(part) > TITLE_WIDTH:
            lines.append("")
        lines[-1] += part
    return "\n".join([f"{what}: {run}", *lines])


def formation_edges(offsets: np.ndarray) -> list[tuple[int, int]]:
    """The pairs of slots ``(N, 2)`` at the formation's smallest slot gap: the lines of a
    grid, the arms of a wedge, the ring of a circle."""
    gaps = np.linalg.norm(offsets[:, None] - offsets[None], axis=-1)
    upper = np.triu_indices(offsets.shape[0], k=1)
    # rotated offsets differ from the scenario's in the last bits
    nearest = gaps[upper].min() * (1.0 + 1e-6)
    return [(int(i), int(j)) for i, j in zip(*upper, strict=True) if gaps[i, j] <= nearest]


def _obstacle_handles(ax: plt.Axes, scenario: Scenario) -> list:
    """Obstacles as filled circles and their penalty margins dashed; legend handles."""
    if not scenario.safety.obstacles:
        return []
    margin = scenario.safety.obstacle_margin_m
    for x, y, radius in scenario.safety.obstacles:
        ax.add_patch(
            Circle(
                (x, y),
                radius,
                facecolor=OBSTACLE_COLOUR,
                edgecolor=OBSTACLE_COLOUR,
                alpha=0.45,
                gid="obstacle",
            )
        )
        if margin > 0:
            ax.add_patch(
                Circle(
                    (x, y),
                    radius + margin,
                    fill=False,
                    edgecolor=OBSTACLE_COLOUR,
                    ls="--",
                    lw=1.0,
                    gid="obstacle-margin",
                )
            )
    handles = [Patch(facecolor=OBSTACLE_COLOUR, alpha=0.45, label="obstacle")]
    if margin > 0:
        handles.append(
            Line2D(
                [], [], color=OBSTACLE_COLOUR, ls="--", lw=1.0, label=f"penalty margin {margin:g} m"
            )
        )
    return handles


@_styled
def trajectory_figure(
    frame: pd.DataFrame, scenario: Scenario | None = None, snapshot_every_s: float = 8.0
) -> plt.Figure:
    """Figs. 3 and 5: UAV paths from their start (circles), the reference path, the formation
    every ``snapshot_every_s`` and, with the ``scenario``, its obstacles.

    Three UAVs are joined into their triangle; more are joined along the formation's edges
    (:func:`formation_edges` of their desired slots), which a polygon would not show.
    """
    if scenario is not None:
        _check_scenario(frame, scenario)
    if not snapshot_every_s > 0:
        raise ValueError(f"snapshot_every_s must be > 0, got {snapshot_every_s!r}")
    times, positions = positions_of(frame)
    n_uav = positions.shape[1]
    colours = uav_colours(n_uav)
    named = n_uav <= LEGEND_MAX_UAVS
    fig, ax = plt.subplots(figsize=(8 if named else 8.8, 6), constrained_layout=True)
    handles = _obstacle_handles(ax, scenario) if scenario is not None else []
    reference = frame[frame["uav"] == frame["uav"].min()]
    ax.plot(reference["ref_x_m"], reference["ref_y_m"], "k--", lw=1.2, label="reference centre")
    for k, colour in enumerate(colours):
        ax.plot(
            positions[:, k, 0],
            positions[:, k, 1],
            color=colour,
            lw=1.5 if named else 1.0,
            label=f"UAV {k + 1}" if named else None,
            gid="uav-path",
        )
        ax.plot(
            *positions[0, k],
            "o",
            color=colour,
            ms=6 if named else 4,
            mec="k",
            mew=0.5,
            gid="uav-start",
        )
    first = frame[frame["step"] == frame["step"].min()].sort_values("uav")
    slots = first[["desired_x_m", "desired_y_m"]].to_numpy()
    edges = formation_edges(slots) if n_uav > 3 else []
    for t in np.arange(0.0, times[-1] + 1e-9, snapshot_every_s):
        row = positions[int(np.argmin(np.abs(times - t)))]
        if n_uav <= 3:
            ax.fill(row[:, 0], row[:, 1], facecolor="none", edgecolor="0.4", lw=0.8)
        else:
            segments = [row[[i, j]] for i, j in edges]
            ax.add_collection(LineCollection(segments, colors="0.4", lw=0.7, gid="formation"))
            ax.plot(row[:, 0], row[:, 1], ".", color="0.25", ms=3)
        ax.plot(*row.mean(axis=0), "x", color="0.3", ms=5)
    handles += [
        Line2D([], [], color="0.4", lw=0.8, label=f"formation every {snapshot_every_s:g} s"),
        Line2D([], [], ls="none", marker="o", mfc="none", mec="k", mew=1.0, ms=6, label="start"),
    ]
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal", adjustable="datalim")
    lines = ax.get_legend_handles_labels()[0]
    ax.legend(handles=[*lines, *handles], loc="best", fontsize=9 if named else 8)
    if not named:
        _uav_colour_bar(fig, ax, colours)
    ax.set_title(_title(frame, "Trajectories"), fontsize=10)
    return fig


def listeners(frame: pd.DataFrame, scenario: Scenario) -> np.ndarray:
    """``(T, N, N)`` whether UAV i listened to UAV j at update instant c (``[c, i, j]``),
    found from the positions in the trace as the closed loop finds it."""
    _check_scenario(frame, scenario)
    _, positions = positions_of(frame)
    return np.stack([listening(scenario, p) for p in positions[:-1]])


def graph_distance_errors(frame: pd.DataFrame, scenario: Scenario) -> pd.DataFrame:
    """Per instant, the max and RMS over the communication graph's pairs of |actual - desired|
    distance (columns ``max_m``, ``rms_m``, indexed by ``time_s``); NaN at an instant without
    a pair."""
    times, positions = positions_of(frame)
    errors = np.abs(metrics.pair_gaps(positions) - scenario.desired_distances())
    links = metrics.pairs_of_graph(listeners(frame, scenario))
    count = links.sum(axis=(1, 2))
    with np.errstate(invalid="ignore"):
        largest = np.where(links, errors, -np.inf).max(axis=(1, 2))
        rms = np.sqrt(np.where(links, errors**2, 0.0).sum(axis=(1, 2)) / count)
    largest[count == 0] = np.nan
    return pd.DataFrame({"max_m": largest, "rms_m": rms}, index=pd.Index(times, name="time_s"))


@_styled
def states_figure(
    frame: pd.DataFrame,
    desired_distances: dict[str, float],
    settle_time_s: float,
    scenario: Scenario | None = None,
) -> plt.Figure:
    """Figs. 4 and 6: states, controls, distances and tracking error over time.

    Up to :data:`~formation_bench.mpc.metrics.PAIR_COLUMNS_MAX_UAVS` UAVs the distance panel
    draws every named pair (``desired_distances`` by :func:`pair_names` name); a larger run
    draws the max and RMS of |actual - desired| distance over its communication graph's
    pairs, which needs its ``scenario``.
    """
    n_uav = frame["uav"].nunique()
    if n_uav > PAIR_COLUMNS_MAX_UAVS and scenario is None:
        raise ValueError(
            f"states_figure: a run of {n_uav} UAVs (more than {PAIR_COLUMNS_MAX_UAVS}) draws "
            "its communication graph's distance errors and needs its scenario"
        )
    colours = uav_colours(n_uav)
    named = n_uav <= LEGEND_MAX_UAVS
    fig, axes = plt.subplots(
        3, 2, figsize=(11 if named else 11.8, 9), sharex=True, constrained_layout=True
    )
    panels = [
        ("speed_m_s", "speed v (m/s)", 1.0),
        ("heading_rad", "heading θ (deg)", 180.0 / np.pi),
        ("accel_m_s2", "acceleration a (m/s²)", 1.0),
        ("turn_rate_rad_s", "turn rate ω (rad/s)", 1.0),
    ]
    for ax, (column, label, scale) in zip(axes.flat[:4], panels, strict=True):
        values = wide(frame, column) * scale
        drawstyle = "steps-post" if column in ("accel_m_s2", "turn_rate_rad_s") else "default"
        for colour, uav in zip(colours, values.columns, strict=True):
            ax.plot(
                values.index,
                values[uav],
                lw=1.2 if named else 0.8,
                color=colour,
                label=f"UAV {uav}",
                drawstyle=drawstyle,
                gid="uav-state",
            )
        ax.set_ylabel(label)
    if named:
        axes[0, 0].legend(fontsize=8, ncols=1 if n_uav <= 3 else 2)
    else:
        _uav_colour_bar(fig, axes[:2, :], colours)
    x, y = wide(frame, "x_m"), wide(frame, "y_m")
    ax = axes[2, 0]
    if n_uav <= PAIR_COLUMNS_MAX_UAVS:
        for name, i, j in pair_names(n_uav):
            distance = np.hypot(x.iloc[:, i] - x.iloc[:, j], y.iloc[:, i] - y.iloc[:, j])
            (line,) = ax.plot(x.index, distance, lw=1.2, label=name)
            ax.axhline(desired_distances[name], color=line.get_color(), ls=":", lw=1)
        ax.set_ylabel("pairwise distance (m)")
        ax.legend(fontsize=8, title="dotted: desired", title_fontsize=8, ncols=1 + (n_uav > 3))
    else:
        errors = graph_distance_errors(frame, scenario)
        palette = _colours()
        ax.plot(
            errors.index,
            errors["max_m"],
            color=palette[2],
            lw=1.2,
            label="max over pairs",
            gid="distance-error-max",
        )
        ax.plot(
            errors.index,
            errors["rms_m"],
            color=palette[0],
            lw=1.2,
            label="RMS over pairs",
            gid="distance-error-rms",
        )
        ax.axvline(settle_time_s, color="0.5", ls="--", lw=1)
        ax.set_yscale("log")
        ax.set_ylabel("|actual - desired| distance (m)")
        ax.legend(
            fontsize=8, title=f"{scenario.communication.graph} graph's pairs", title_fontsize=8
        )
    ax.set_xlabel("time (s)")
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
    uavs = sorted(frame["uav"].unique())
    small = len(uavs) <= 10
    fig, ax = plt.subplots(figsize=(10, max(3.2, 1.2 + 0.3 * len(uavs))), constrained_layout=True)
    colours = uav_colours(len(uavs))
    n_instants = frame.loc[frame["uav"] == uavs[0], "step"].max()
    for row, uav in enumerate(uavs):
        times = frame.loc[(frame["uav"] == uav) & frame["solved"], "time_s"].to_numpy()
        ax.vlines(times, row + 0.6, row + 1.4, lw=1.2 if small else 0.8, color=colours[row])
        ax.text(
            1.005,
            row + 1,
            f"{times.size}/{n_instants}",
            transform=ax.get_yaxis_transform(),
            va="center",
            fontsize=9 if small else 7,
        )
    ax.set_yticks(
        range(1, len(uavs) + 1), [f"UAV {u}" for u in uavs], fontsize=None if small else 8
    )
    ax.set_ylim(0.4, len(uavs) + 0.6)
    ax.set_xlabel("time (s)")
    ax.set_title(_title(frame, "Solve instants (count / update instants)"), fontsize=10)
    return fig


def collision_instants(frame: pd.DataFrame, safety_radius_m: float) -> np.ndarray:
    """``(T,)`` the periods in which some pair came closer than ``safety_radius_m``, as the
    ``collisions`` metric counts them."""
    _, positions = positions_of(frame)
    return metrics.collision_periods_at(positions, safety_radius_m).any(axis=(1, 2))


def obstacle_clearance(frame: pd.DataFrame, scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """The smallest distance of a UAV to an obstacle's edge at every instant ``(T + 1,)``
    (negative inside), and ``(T,)`` the periods in which a UAV was inside an obstacle, as the
    ``obstacle_intrusions`` metric counts them."""
    _check_scenario(frame, scenario)
    _, positions = positions_of(frame)
    obstacles = np.asarray(scenario.safety.obstacles, dtype=np.float64).reshape(-1, 3)
    relative = positions[:, :, None] - obstacles[:, :2]  # (T + 1, N, K, 2)
    clearance = np.linalg.norm(relative, axis=-1) - obstacles[:, 2]
    inside = metrics.obstacle_periods_at(positions, obstacles)
    return clearance.min(axis=(1, 2)), inside.any(axis=(1, 2))


def plans_per_instant(frame: pd.DataFrame, scenario: Scenario) -> pd.DataFrame:
    """Per update instant (``time_s``, the last instant left out): plans ``sent`` (one per
    listener of a new plan), ``lost`` by the links and received ``late``, over all UAVs."""
    listens = listeners(frame, scenario)
    solved = wide(frame, "solved").to_numpy(dtype=bool)[:-1]
    by_instant = frame.groupby("time_s")[["plans_lost", "plans_late"]].sum()
    return pd.DataFrame(
        {
            "sent": metrics.plans_sent_at(solved, listens),
            "lost": by_instant["plans_lost"].to_numpy()[:-1],
            "late": by_instant["plans_late"].to_numpy()[:-1],
        },
        index=by_instant.index[:-1],
    )


_BESIDE = {"fontsize": 8, "loc": "upper left", "bbox_to_anchor": (1.01, 1.0)}
"""Legend placement right of a panel: a legend inside would hide the lines at some instants."""


def _spans(count: int) -> str:
    return f"{count} span" if count == 1 else f"{count} spans"


def _shade(ax: plt.Axes, times: np.ndarray, periods: np.ndarray, colour: str, gid: str) -> int:
    """Shade each run of True ``periods`` (period c spans times[c] .. times[c + 1]); returns
    the number of runs."""
    edges = np.diff(np.concatenate(([0], periods.astype(np.int8), [0])))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    for start, end in zip(starts, ends, strict=True):
        ax.axvspan(times[start], times[end], color=colour, alpha=0.25, lw=0, gid=gid)
    return starts.size


@_styled
def separation_figure(frame: pd.DataFrame, scenario: Scenario) -> plt.Figure:
    """The smallest separation of two UAVs over time against the safety radius, collision
    periods shaded; with obstacles, the smallest clearance to an obstacle's edge; when plans
    can be lost or late, the plans sent, lost and late at every instant."""
    _check_scenario(frame, scenario)
    times, positions = positions_of(frame)
    has_obstacles = bool(scenario.safety.obstacles)
    faults = scenario.communication_faults
    n_panels = 1 + has_obstacles + faults
    fig, axes = plt.subplots(
        n_panels,
        1,
        figsize=(10, 1.0 + 2.7 * n_panels),
        sharex=True,
        squeeze=False,
        constrained_layout=True,
    )
    axes = list(axes[:, 0])
    separation = metrics.separation_at(positions)
    slot_gap = scenario.desired_distances()[np.triu_indices(scenario.n_uav, k=1)].min()
    ax = axes[0]
    ax.plot(times, separation, color="k", lw=1.2, label="closest pair", gid="separation")
    ax.axhline(slot_gap, color="0.5", ls=":", lw=1, label=f"closest slots {slot_gap:.3g} m")
    radius = scenario.safety.safety_radius_m
    alarm = _colours()[2]
    ax.axhline(radius, color=alarm, ls="--", lw=1.2, label=f"safety radius {radius:g} m")
    runs = _shade(ax, times, collision_instants(frame, radius), alarm, "collision")
    handles = ax.get_legend_handles_labels()[0]
    handles.append(Patch(color=alarm, alpha=0.25, label=f"pair closer than it ({_spans(runs)})"))
    ax.legend(handles=handles, **_BESIDE)
    ax.set_ylim(0.0, max(separation.max(), slot_gap, radius) * 1.08)
    ax.set_ylabel("smallest separation (m)")
    panel = 1
    if has_obstacles:
        clearance, inside = obstacle_clearance(frame, scenario)
        ax = axes[panel]
        panel += 1
        ax.plot(times, clearance, color="k", lw=1.2, label="closest UAV", gid="clearance")
        ax.axhline(0.0, color=OBSTACLE_COLOUR, lw=1.2, label="obstacle edge")
        margin = scenario.safety.obstacle_margin_m
        if margin > 0:
            ax.axhline(
                margin, color=OBSTACLE_COLOUR, ls="--", lw=1.0, label=f"penalty margin {margin:g} m"
            )
        runs = _shade(ax, times, inside, OBSTACLE_COLOUR, "intrusion")
        handles = ax.get_legend_handles_labels()[0]
        handles.append(
            Patch(color=OBSTACLE_COLOUR, alpha=0.25, label=f"inside an obstacle ({_spans(runs)})")
        )
        ax.legend(handles=handles, **_BESIDE)
        # far from the obstacles the clearance is hundreds of metres; near them, metres matter
        ax.set_yscale("symlog", linthresh=max(margin, 1.0) * 5)
        ax.set_ylim(bottom=min(-margin, -1.0, clearance.min() * 1.2))
        ax.set_ylabel("clearance to an obstacle (m)")
    if faults:
        plans = plans_per_instant(frame, scenario)
        ax = axes[panel]
        # period c runs from instant c to c + 1: one step per period
        for column, label, colour, fill in (
            ("sent", "sent", "0.8", True),
            ("lost", "lost", alarm, True),
            ("late", "received late", _colours()[0], False),
        ):
            ax.stairs(
                plans[column].to_numpy(),
                times,
                fill=fill,
                color=colour,
                lw=1.2,
                label=f"{label} ({plans[column].sum()} in all)",
                gid=f"plans-{column}",
            )
        ax.set_ylabel("plans per instant")
        ax.set_ylim(bottom=0)
        ax.legend(**_BESIDE)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(_title(frame, "Separation"), fontsize=10)
    return fig


def save(fig: plt.Figure, path) -> None:
    """Save as PNG at a legible resolution and free the figure."""
    fig.savefig(path, dpi=120)
    plt.close(fig)


def named_desired_distances(scenario: Scenario) -> dict[str, float]:
    """The desired distance of every named UAV pair (:func:`pair_names`), as
    :func:`states_figure` takes them."""
    desired = scenario.desired_distances()
    return {name: float(desired[i, j]) for name, i, j in pair_names(scenario.n_uav)}


def write_run_figures(
    frame: pd.DataFrame,
    scenario: Scenario,
    out_dir: Path,
    suffix: str,
    fig_numbers: tuple[int, int],
) -> list[Path]:
    """Trajectory, states and separation figures of one run (its trace table and scenario);
    returns the paths written.

    The first two are numbered as the paper's (``fig3_trajectory_no_trigger.png``, ...); the
    separation figure, which the paper has not, is ``separation_<suffix>.png``.
    """
    desired_by_name = named_desired_distances(scenario)
    trajectory = out_dir / f"fig{fig_numbers[0]}_trajectory_{suffix}.png"
    states = out_dir / f"fig{fig_numbers[1]}_states_{suffix}.png"
    separation = out_dir / f"separation_{suffix}.png"
    save(trajectory_figure(frame, scenario), trajectory)
    settle_time_s = scenario.evaluation.settle_time_s
    save(states_figure(frame, desired_by_name, settle_time_s, scenario), states)
    save(separation_figure(frame, scenario), separation)
    return [trajectory, states, separation]


def write_trigger_figure(frame: pd.DataFrame, out_dir: Path, name: str) -> Path:
    """Fig. 7 of one run (its trace table) as ``out_dir/name``."""
    path = out_dir / name
    save(trigger_figure(frame), path)
    return path
