"""The disturbance and fault families of the harness, and the report's sections of them.

The families are declared by the harness (:mod:`formation_bench.mpc.families`); a test adds
one here, without editing the analysis, and the report gives its levels their own blocks. The
disturbance settings are fixed fields of the scenario's groups and a stored run is rebuilt as
the package's ``Scenario``, so a new disturbance kind the report can see is a new way of
claiming those settings: here gusts split from the mean wind, which act differently (a random
push per UAV against a steady drift of the whole formation).
"""

import json
from dataclasses import dataclass

import numpy as np
import pandas as pd
import pytest

from formation_bench.analysis import suite_sections as sections
from formation_bench.cli.main import main
from formation_bench.experiments.suite import parse_suite
from formation_bench.experiments.sweep import run_sweep
from formation_bench.fields import setting
from formation_bench.mpc import families
from formation_bench.mpc.families import (
    ScenarioFamily,
    UnclaimedDisturbanceError,
    register_family,
    scenario_families,
    unregister_family,
)
from formation_bench.mpc.scenario import CommunicationSettings, DisturbanceSettings, get_scenario
from formation_bench.pipeline.spec import canonical_json, config_of
from formation_bench.plugins import DuplicateNameError

PACKAGE_FAMILIES = ["wind", "noise", "packet loss", "delay", "mismatch"]
OPTIMIZERS = ("modified-bso", "pso")
LEVELS = {
    # label: (overrides of the paper scenario, shift of the error metrics)
    "nominal": ({}, 0.0),
    "gust-1": ({"gust_std_m_s": 1.0}, 1.0),
    "crosswind-3": ({"wind_mean_m_s": (0.0, 3.0)}, 2.0),
}


@pytest.fixture
def registry():
    """The family registry, restored (contents and order) after the test."""
    saved = list(families.FAMILIES)
    yield families.FAMILIES
    families.FAMILIES[:] = saved


def split_wind() -> None:
    """Register gusts and mean wind as two families in place of the package's wind."""
    unregister_family("wind")
    register_family(
        ScenarioFamily(
            "mean wind",
            ("wind_mean_m_s",),
            lambda s: any(w != 0 for w in s.disturbances.wind_mean_m_s),
            lambda s: (float(np.hypot(*s.disturbances.wind_mean_m_s)),),
        )
    )
    register_family(
        ScenarioFamily(
            "gusts",
            ("gust_std_m_s", "gust_time_constant_s"),
            lambda s: s.disturbances.gust_std_m_s > 0,
            lambda s: (s.disturbances.gust_std_m_s,),
        )
    )


def fake_results(seeds: int = 5) -> pd.DataFrame:
    """Stored rows of the paper scenario at every level of :data:`LEVELS` (seeded numbers)."""
    rng = np.random.default_rng(5)
    rows = []
    for label, (overrides, shift) in LEVELS.items():
        config = canonical_json(config_of(get_scenario("paper", **overrides)))
        for k, optimizer in enumerate(OPTIMIZERS):
            for seed in range(seeds):
                error = 1.0 + shift + 0.3 * k + 0.1 * rng.random()
                rows.append(
                    {
                        "suite": "fake",
                        "scenario": label,
                        "scenario_name": "paper",
                        "scenario_overrides": json.dumps(overrides, sort_keys=True),
                        "scenario_config": config,
                        "optimizer": optimizer,
                        "optimizer_name": optimizer,
                        "trigger": True,
                        "budget": "max_evaluations=1200",
                        "seed": seed,
                        "tracking_error_max_m": error,
                        "distance_error_rms_m": error / 10,
                        "distance_error_max_m_max": error / 5,
                        "solves_total": int(rng.integers(200, 300)),
                        "min_separation_m": 5.0 - error,
                    }
                )
    return pd.DataFrame(rows)


def block_table(markdown: str, heading: str) -> list[str]:
    """The table rows under ``heading`` up to the next heading."""
    after = markdown.split(heading + "\n", 1)[1].split("\n### ", 1)[0]
    return [line for line in after.splitlines() if line.startswith("|")]


# --- the package's families ----------------------------------------------------------------


def test_every_disturbance_and_fault_setting_is_claimed_by_exactly_one_family():
    assert [f.name for f in families.FAMILIES] == PACKAGE_FAMILIES
    assert families.unclaimed_settings() == ()
    claims = [name for family in families.FAMILIES for name in family.settings]
    assert sorted(claims) == sorted(families.disturbance_settings())
    # the graph is the swarm section's business, the penalties the obstacles section's
    assert "graph" not in claims and "w_obstacle" not in claims
    # the exempted settings are the communication group's own, so a typo exempts nothing
    assert set(families.NOT_DISTURBANCES) < set(CommunicationSettings.__dataclass_fields__)


def test_the_analysis_reads_the_families_of_the_harness():
    assert sections.FAMILIES is families.FAMILIES
    assert not hasattr(sections, "Family")


@pytest.mark.parametrize(
    ("overrides", "expected"),
    [
        ({}, []),
        ({"gust_std_m_s": 1.0}, ["wind"]),
        ({"wind_mean_m_s": (0.0, 3.0)}, ["wind"]),
        ({"heading_noise_std_rad": 0.01}, ["noise"]),
        ({"packet_loss": 0.3, "loss_correlation": 0.7}, ["packet loss"]),
        ({"delay_jitter_steps": 1}, ["delay"]),
        ({"plant_turn_rate_gain": 0.8}, ["mismatch"]),
        ({"gust_std_m_s": 0.5, "packet_loss": 0.1}, ["wind", "packet loss"]),
        # claimed settings that disturb nothing alone: nominal, as before
        ({"gust_time_constant_s": 5.0}, []),
        ({"loss_correlation": 0.5}, []),
        # the graph is no disturbance
        ({"graph": "ring"}, []),
    ],
)
def test_a_scenario_has_the_families_its_settings_make(overrides, expected):
    scenario = get_scenario("paper", **overrides)
    assert [f.name for f in scenario_families(scenario)] == expected


# --- registration --------------------------------------------------------------------------


def test_registration_refuses_a_setting_another_family_claims(registry):
    gusts = ScenarioFamily("gusts", ("gust_std_m_s",), lambda s: True, lambda s: ())
    with pytest.raises(
        ValueError, match=r"Scenario\.gust_std_m_s, already claimed by family 'wind'"
    ):
        register_family(gusts)
    assert [f.name for f in registry] == PACKAGE_FAMILIES


@pytest.mark.parametrize(
    ("family", "error", "message"),
    [
        (ScenarioFamily("ring", ("graph",), bool, tuple), ValueError, "who listens to whom"),
        (ScenarioFamily("walls", ("w_obstacle",), bool, tuple), ValueError, "not a setting"),
        (ScenarioFamily("nominal", ("gust_std_m_s",), bool, tuple), ValueError, "'nominal'"),
        (ScenarioFamily("a + b", ("gust_std_m_s",), bool, tuple), ValueError, "joins"),
        (ScenarioFamily("wind", ("gust_std_m_s",), bool, tuple), DuplicateNameError, "already"),
        (ScenarioFamily("nothing", (), bool, tuple), ValueError, "at least one setting"),
    ],
)
def test_registration_refuses_a_family_that_claims_no_disturbance(registry, family, error, message):
    with pytest.raises(error, match=message):
        register_family(family)
    assert [f.name for f in registry] == PACKAGE_FAMILIES


# --- an unclaimed disturbance is an error, not nominal -------------------------------------


def test_a_scenario_disturbed_in_an_unclaimed_setting_is_refused(registry):
    unregister_family("noise")
    noisy = get_scenario("paper", position_noise_std_m=0.1)
    with pytest.raises(UnclaimedDisturbanceError, match=r"Scenario\.position_noise_std_m = 0\.1"):
        scenario_families(noisy)
    # the settings no family claims are harmless where the scenario keeps them nominal
    assert scenario_families(get_scenario("paper", gust_std_m_s=1.0))[0].name == "wind"
    assert scenario_families(get_scenario("paper")) == ()


@dataclass(frozen=True)
class IcingDisturbances(DisturbanceSettings):
    """The package's disturbances and one more, as a new disturbance added to the harness."""

    icing_drag: float = setting(0.0, low=0.0, doc="Drag of ice on the wings, 1/s")


def test_a_new_disturbance_setting_without_a_family_is_refused():
    # as if the setting were added to the disturbance group and no family claimed it
    iced = get_scenario("paper").with_overrides(disturbances=IcingDisturbances(icing_drag=0.1))
    with pytest.raises(UnclaimedDisturbanceError, match=r"Scenario\.icing_drag = 0\.1"):
        scenario_families(iced)
    calm = get_scenario("paper").with_overrides(disturbances=IcingDisturbances())
    assert scenario_families(calm) == ()


def test_the_report_refuses_runs_of_an_unclaimed_disturbance_rather_than_call_them_nominal(
    registry, tmp_path
):
    unregister_family("wind")
    with pytest.raises(UnclaimedDisturbanceError, match=r"Scenario\.gust_std_m_s"):
        sections.write_sections(fake_results(), tmp_path, figures=False)
    assert not (tmp_path / "robustness.md").exists()


# --- a registered family gets its own blocks --------------------------------------------------


def test_a_family_registered_here_gets_its_own_blocks_in_the_robustness_section(registry, tmp_path):
    results = fake_results()
    before = sections.scenario_columns(results).drop_duplicates("scenario")
    assert set(before["family"]) == {"nominal", "wind"}
    split_wind()
    markdown = sections.write_sections(results, tmp_path, figures=False)
    written = (tmp_path / "robustness.md").read_text()
    assert markdown.rstrip() == written.rstrip()
    headings = [line for line in written.splitlines() if line.startswith("### ")]
    assert headings == [
        "### nominal",
        "### mean wind crosswind-3 against nominal",
        "### gusts gust-1 against nominal",
    ]
    for heading in headings[1:]:
        rows = block_table(written, heading)
        assert [r.split("|")[1].strip() for r in rows[2:4]] == list(OPTIMIZERS)
        assert " vs " in rows[2]  # against the nominal median
    table = pd.read_csv(tmp_path / "robustness.csv").drop_duplicates("scenario")
    assert dict(zip(table["scenario"], table["family"], strict=True)) == {
        "nominal": "nominal",
        "crosswind-3": "mean wind",
        "gust-1": "gusts",
    }


# --- end to end: a real sweep through `formation-bench report` -----------------------------

SUITE = """
name = "tiny-families"
seeds = 2
triggers = [true]

[[optimizers]]
name = "modified-bso"
overrides = { max_iterations = 2 }

[[optimizers]]
name = "pso"
overrides = { max_iterations = 2 }

[[scenarios]]
name = "paper"
label = "nominal"
overrides = { n_steps = 10, settle_time_s = 1.0 }

[[scenarios]]
name = "paper"
label = "gust-1"
overrides = { n_steps = 10, settle_time_s = 1.0, gust_std_m_s = 1.0 }

[[scenarios]]
name = "paper"
label = "crosswind-3"
overrides = { n_steps = 10, settle_time_s = 1.0, wind_mean_m_s = [0.0, 3.0] }
"""


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny-families")
    suite = parse_suite(SUITE, out / "tiny.toml")
    run_sweep(suite, out, jobs=1, progress=False, log=lambda _: None)
    return out


@pytest.mark.slow
def test_the_report_of_a_real_sweep_has_the_registered_familys_section(registry, sweep, capsys):
    split_wind()
    assert main(["report", str(sweep), "--no-figures", "--out", str(sweep / "split")]) == 0
    capsys.readouterr()
    report = (sweep / "split" / "report.md").read_text()
    for heading in (
        "### gusts gust-1 against nominal",
        "### mean wind crosswind-3 against nominal",
    ):
        rows = block_table(report, heading)
        assert {r.split("|")[1].strip() for r in rows[2:]} >= {
            f"{o}[max_iterations=2]" for o in OPTIMIZERS
        }
    unregister_family("gusts")
    code = main(["report", str(sweep), "--no-figures", "--out", str(sweep / "unclaimed")])
    error = capsys.readouterr().err
    assert code == 2
    assert error.startswith("formation-bench report: error: Scenario.gust_std_m_s = 1.0 ")
    assert error.count("\n") == 1, error
    assert not (sweep / "unclaimed").exists()
