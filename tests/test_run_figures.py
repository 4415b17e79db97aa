"""The figures of one run draw any number of UAVs, the obstacles, the communication graph's
distance errors, the separation and the plans lost and late, and agree with the metrics."""

from __future__ import annotations

import json
import math

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.collections import LineCollection
from matplotlib.patches import Circle, Polygon, StepPatch

from formation_bench.analysis import run_figures as figures
from formation_bench.cli.main import main
from formation_bench.mpc import metrics
from formation_bench.mpc.formations import FormationShape, formation_offsets
from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import get_optimizer
from formation_bench.pipeline.runner import execute
from formation_bench.pipeline.spec import RunSpec

STEPS = {"n_steps": 30, "settle_time_s": 2.0}
"""Short runs: 6 s, 30 instants."""

RUNS = {
    # name: (registered scenario, overrides beyond STEPS)
    "paper": ("paper", {}),
    "obstacles": (
        "paper",
        # one around UAV 1's start (an intrusion at once), one on the reference line ahead
        {"obstacles": ((-7.0, -18.0, 4.0), (40.0, -4.0, 5.0)), "obstacle_margin_m": 3.0},
    ),
    "swarm-5": ("swarm-5", {}),
    "swarm-10-faults": (
        "swarm-10",
        {"graph": "k-nearest", "graph_neighbours": 3, "packet_loss": 0.3, "delay_jitter_steps": 2},
    ),
}


@pytest.fixture(scope="module")
def outcomes():
    """One short PSO run of every entry of :data:`RUNS`."""
    optimizer = get_optimizer("pso", population_size=10, max_iterations=3)
    done = {}
    for label, (name, overrides) in RUNS.items():
        scenario = get_scenario(name, **STEPS, **overrides)
        spec = RunSpec.of("pso", optimizer, name, scenario, trigger=False, seed=1)
        done[label] = execute(spec)
    return done


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


def _with_gid(artists, gid):
    return [a for a in artists if a.get_gid() == gid]


def _snapshots(outcome, every_s=8.0):
    return np.arange(0.0, outcome.trace.times[-1] + 1e-9, every_s).size


@pytest.mark.parametrize("label", list(RUNS))
def test_trajectory_draws_every_uav_its_start_and_the_obstacles(outcomes, label):
    outcome = outcomes[label]
    scenario = outcome.trace.scenario
    n_uav = scenario.n_uav
    fig = figures.trajectory_figure(outcome.frame, scenario, snapshot_every_s=2.0)
    ax = fig.axes[0]
    paths = _with_gid(ax.lines, "uav-path")
    assert len(paths) == n_uav
    for k, line in enumerate(paths):
        np.testing.assert_array_equal(line.get_xydata(), outcome.trace.states[:, k, :2])
    starts = _with_gid(ax.lines, "uav-start")
    assert [tuple(s.get_xydata()[0]) for s in starts] == [
        tuple(p) for p in outcome.trace.states[0, :, :2]
    ]
    assert len({line.get_color() for line in paths}) == n_uav
    obstacles = _with_gid(ax.patches, "obstacle")
    margins = _with_gid(ax.patches, "obstacle-margin")
    assert len(obstacles) == len(margins) == len(scenario.safety.obstacles)
    for circle, margin, (x, y, r) in zip(
        obstacles, margins, scenario.safety.obstacles, strict=True
    ):
        assert isinstance(circle, Circle) and circle.get_fill()
        assert circle.center == (x, y) and circle.radius == r
        assert not margin.get_fill() and margin.get_linestyle() == "--"
        assert margin.radius == pytest.approx(r + scenario.safety.obstacle_margin_m)
    snapshots = _snapshots(outcome, 2.0)
    formations = _with_gid(ax.collections, "formation")
    polygons = [p for p in ax.patches if isinstance(p, Polygon)]
    if n_uav <= 3:
        assert len(polygons) == snapshots and not formations
    else:
        edges = figures.formation_edges(np.asarray(scenario.formation_offsets))
        assert len(formations) == snapshots and not polygons
        assert all(len(c.get_segments()) == len(edges) for c in formations)
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    named = [t for t in legend if t.startswith("UAV ")]
    if n_uav <= figures.LEGEND_MAX_UAVS:
        assert named == [f"UAV {k}" for k in range(1, n_uav + 1)] and len(fig.axes) == 1
    else:
        assert not named and len(fig.axes) == 2  # the colour bar instead
        assert fig.axes[1].get_ylabel() == "UAV"
    assert ("obstacle" in legend) == bool(scenario.safety.obstacles)


def test_formation_edges_join_neighbouring_slots_whatever_the_heading():
    spacing = 10.0
    grid = formation_offsets(FormationShape.GRID, 10, spacing)  # rows of 4, 4 and 2
    edges = figures.formation_edges(grid)
    assert len(edges) == (3 + 3 + 1) + (4 + 2)  # along the rows, then between them
    for i, j in edges:
        assert np.linalg.norm(grid[i] - grid[j]) == pytest.approx(spacing)
    wedge = formation_offsets(FormationShape.WEDGE, 5, spacing)
    assert sorted(figures.formation_edges(wedge)) == [(0, 1), (0, 2), (1, 3), (2, 4)]
    circle = formation_offsets(FormationShape.CIRCLE, 7, spacing)
    assert len(figures.formation_edges(circle)) == 7
    turn = 0.7
    rotation = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])
    assert figures.formation_edges(grid @ rotation.T) == edges


@pytest.mark.parametrize("label", ["paper", "obstacles"])
def test_states_of_a_small_run_draw_every_named_pair(outcomes, label):
    outcome = outcomes[label]
    scenario = outcome.trace.scenario
    desired = scenario.desired_distances()
    by_name = {name: float(desired[i, j]) for name, i, j in metrics.pair_names(scenario.n_uav)}
    fig = figures.states_figure(outcome.frame, by_name, scenario.evaluation.settle_time_s, scenario)
    assert len(_with_gid(fig.axes[0].lines, "uav-state")) == scenario.n_uav
    distance_panel = fig.axes[4]
    labels = [t.get_text() for t in distance_panel.get_legend().get_texts()]
    assert labels == [name for name, _, _ in metrics.pair_names(scenario.n_uav)]


@pytest.mark.parametrize("label", ["swarm-5", "swarm-10-faults"])
def test_states_of_a_swarm_draw_the_graph_distance_errors_the_metrics_measure(outcomes, label):
    outcome = outcomes[label]
    trace, scenario = outcome.trace, outcome.trace.scenario
    fig = figures.states_figure(outcome.frame, {}, scenario.evaluation.settle_time_s, scenario)
    for ax in fig.axes[:4]:
        assert len(_with_gid(ax.lines, "uav-state")) == scenario.n_uav
    if scenario.n_uav <= figures.LEGEND_MAX_UAVS:
        legend = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
        assert legend == [f"UAV {k}" for k in range(1, scenario.n_uav + 1)]
    else:
        assert fig.axes[-1].get_ylabel() == "UAV"  # a colour bar, no legend of UAVs
        assert fig.axes[0].get_legend() is None
    (largest,) = _with_gid(fig.axes[4].lines, "distance-error-max")
    (rms,) = _with_gid(fig.axes[4].lines, "distance-error-rms")
    settled = trace.times >= scenario.evaluation.settle_time_s - 1e-9
    measured = metrics.compute_metrics(trace)
    # the figure finds the graph from the positions, the metrics read the loop's log
    assert largest.get_ydata()[settled].max() == pytest.approx(
        measured.distance_error_max_m_max, rel=1e-12
    )
    errors = metrics.pair_distance_errors(trace)[metrics.graph_pairs(trace)].reshape(-1)
    counts = metrics.graph_pairs(trace).sum(axis=(1, 2))
    pooled = np.sqrt(
        np.sum(rms.get_ydata()[settled] ** 2 * counts[settled]) / counts[settled].sum()
    )
    assert pooled == pytest.approx(measured.distance_error_rms_m, rel=1e-12)
    assert np.all(rms.get_ydata() <= largest.get_ydata() + 1e-12)
    assert errors.size == counts.sum()


def test_a_swarm_states_figure_needs_the_scenario_and_the_right_one(outcomes):
    frame = outcomes["swarm-5"].frame
    with pytest.raises(ValueError, match="needs its scenario"):
        figures.states_figure(frame, {}, 2.0)
    with pytest.raises(ValueError, match="has 3 UAVs but the trace has 5"):
        figures.separation_figure(frame, get_scenario("paper"))
    with pytest.raises(ValueError, match="snapshot_every_s must be > 0"):
        figures.trajectory_figure(frame, snapshot_every_s=0.0)


def _shaded_seconds(ax, gid):
    spans = _with_gid(ax.patches, gid)
    return sum(span.get_width() for span in spans), len(spans)


@pytest.mark.parametrize("label", list(RUNS))
def test_separation_figure_shows_what_the_metrics_count(outcomes, label):
    outcome = outcomes[label]
    trace, scenario = outcome.trace, outcome.trace.scenario
    measured = metrics.compute_metrics(trace)
    fig = figures.separation_figure(outcome.frame, scenario)
    panels = [ax for ax in fig.axes if ax.get_ylabel()]
    assert len(panels) == 1 + bool(scenario.safety.obstacles) + scenario.communication_faults
    ax = panels[0]
    (separation,) = _with_gid(ax.lines, "separation")
    np.testing.assert_allclose(separation.get_ydata(), metrics.separation_over_time(trace))
    assert scenario.safety.safety_radius_m in [line.get_ydata()[0] for line in ax.lines]
    collided = metrics.collision_periods(trace).any(axis=(1, 2))
    seconds, _ = _shaded_seconds(ax, "collision")
    assert seconds == pytest.approx(collided.sum() * scenario.timing.period_s)
    assert (seconds > 0) == (measured.collisions > 0)
    panel = 1
    if scenario.safety.obstacles:
        ax = panels[panel]
        panel += 1
        (clearance,) = _with_gid(ax.lines, "clearance")
        obstacles = np.asarray(scenario.safety.obstacles)
        gaps = np.linalg.norm(trace.states[:, :, None, :2] - obstacles[:, :2], axis=-1)
        np.testing.assert_allclose(clearance.get_ydata(), (gaps - obstacles[:, 2]).min(axis=(1, 2)))
        inside = metrics.obstacle_periods(trace).any(axis=(1, 2))
        seconds, _ = _shaded_seconds(ax, "intrusion")
        assert seconds == pytest.approx(inside.sum() * scenario.timing.period_s)
        assert (seconds > 0) == (measured.obstacle_intrusions > 0)
    if scenario.communication_faults:
        ax = panels[panel]
        drawn = {
            gid: _with_gid(ax.patches, f"plans-{gid}")[0].get_data().values
            for gid in ("sent", "lost", "late")
        }
        assert all(isinstance(p, StepPatch) for p in ax.patches if p.get_gid())
        assert drawn["sent"].sum() == measured.plans_sent > 0
        assert drawn["lost"].sum() == measured.plans_lost > 0
        assert drawn["late"].sum() == measured.plans_late > 0
        np.testing.assert_array_equal(drawn["lost"], trace.plans_lost.sum(axis=1))


def test_the_obstacle_run_meets_its_obstacle(outcomes):
    # otherwise the shading checks above hold trivially
    assert metrics.compute_metrics(outcomes["obstacles"].trace).obstacle_intrusions > 0


def test_the_trace_table_carries_the_network_and_the_wind(outcomes):
    outcome = outcomes["swarm-10-faults"]
    trace, frame = outcome.trace, outcome.frame
    n_steps = trace.controls.shape[0]
    for column, values in (
        ("neighbours", trace.neighbours.sum(axis=2)),
        ("plans_lost", trace.plans_lost),
        ("plans_late", trace.plans_late),
        ("wind_x_m_s", trace.wind[:, :, 0]),
        ("wind_y_m_s", trace.wind[:, :, 1]),
    ):
        table = figures.wide(frame, column).to_numpy()
        np.testing.assert_array_equal(table[:n_steps], values)
        last = table[n_steps]
        assert np.all(np.isnan(last)) if column.startswith("wind") else np.all(last == 0)
    assert frame["neighbours"].max() == 3  # k-nearest, k = 3
    assert frame["plans_lost"].dtype == frame["neighbours"].dtype == np.int64


def test_solve_instants_get_a_row_and_a_colour_per_uav(outcomes):
    outcome = outcomes["swarm-10-faults"]
    fig = figures.trigger_figure(outcome.frame)
    rows = [c for c in fig.axes[0].collections if isinstance(c, LineCollection)]
    assert len(rows) == 10
    assert len({tuple(np.round(c.get_color()[0], 6)) for c in rows}) == 10
    assert [len(c.get_segments()) for c in rows] == list(outcome.trace.solved.sum(axis=0))


def test_uav_colours_are_distinct_up_to_the_largest_swarm():
    for n_uav in (2, 3, 6, 7, 10, 25, 60):
        colours = figures.uav_colours(n_uav)
        assert len(colours) == len(set(colours)) == n_uav


def test_a_long_scenario_label_wraps_at_commas(outcomes):
    frame = outcomes["swarm-5"].frame.copy()
    label = "swarm-5[" + ",".join(f"field_{k}={k}.5" for k in range(12)) + "]"
    frame["scenario"] = label
    title = figures._title(frame, "Trajectories")
    lines = title.split("\n")
    assert len(lines) >= 3 and "".join(lines[1:]) == label
    assert all(len(line) <= figures.TITLE_WIDTH for line in lines)


@pytest.mark.parametrize(
    ("scenario", "extra", "suffix"),
    [
        ("swarm-10", ["--set", "graph=ring"], "trigger"),
        ("paper-obstacles", [], "trigger"),
        ("paper", ["--set", "scenario.packet_loss=0.3", "--no-trigger"], "no_trigger"),
    ],
)
@pytest.mark.slow
def test_run_writes_every_figure(tmp_path, scenario, extra, suffix):
    out = tmp_path / "run"
    args = ["run", "--optimizer", "pso", "--scenario", scenario, "--seed", "2"]
    short = ["--set", "n_steps=15", "--set", "settle_time_s=1", "--set", "max_iterations=2"]
    assert main([*args, *short, *extra, "--out", str(out)]) == 0
    numbers = (3, 4) if suffix == "no_trigger" else (5, 6)
    for name in (
        f"fig{numbers[0]}_trajectory_{suffix}.png",
        f"fig{numbers[1]}_states_{suffix}.png",
        f"fig7_solve_instants_{suffix}.png",
        f"separation_{suffix}.png",
    ):
        assert (out / name).stat().st_size > 10_000, name
    (record,) = json.loads((out / "metrics.json").read_text())
    assert record["scenario"].startswith(scenario)
