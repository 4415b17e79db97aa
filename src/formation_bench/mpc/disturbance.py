"""What the world does that the prediction model does not: wind, measurement noise and
model mismatch. They act on the plant and on what each UAV measures; the prediction model
stays eq. (1).

- **Wind** moves every UAV's position by the wind velocity, held over each period: a
  constant part (``wind_mean_m_s``) plus each UAV's gusts, an Ornstein-Uhlenbeck process per
  axis with stationary standard deviation ``gust_std_m_s`` and correlation time
  ``gust_time_constant_s``, sampled exactly at the update instants and started from its
  stationary distribution.
- **Measurement noise**: each UAV solves from its own state plus independent normal noise
  (``position_noise_std_m`` per axis, ``heading_noise_std_rad``, ``speed_noise_std_m_s``).
- **Model mismatch**: the plant's acceleration and turn rate are ``plant_accel_gain`` and
  ``plant_turn_rate_gain`` times the commanded ones.

The wind and the noise have Generators of their own, drawn at every instant, so a seed's
disturbances are the same for every optimiser.
"""

from __future__ import annotations

import math

import numpy as np

from formation_bench.mpc.model import step_plant
from formation_bench.mpc.scenario import Scenario


class Disturbances:
    """The plant side of a run: its step under wind and mismatch, and the noisy measurements."""

    def __init__(
        self, scenario: Scenario, wind_rng: np.random.Generator, noise_rng: np.random.Generator
    ) -> None:
        self.scenario = scenario
        self.wind_rng = wind_rng
        self.noise_rng = noise_rng
        n_uav = scenario.n_uav
        self.gusts = np.zeros((n_uav, 2))
        if scenario.disturbances.gust_std_m_s > 0:
            self.gusts = wind_rng.normal(0.0, scenario.disturbances.gust_std_m_s, size=(n_uav, 2))
        self.noise_std = np.array(
            [
                scenario.disturbances.position_noise_std_m,
                scenario.disturbances.position_noise_std_m,
                scenario.disturbances.heading_noise_std_rad,
                scenario.disturbances.speed_noise_std_m_s,
            ]
        )
        disturbances = scenario.disturbances
        self.gains = np.array([disturbances.plant_accel_gain, disturbances.plant_turn_rate_gain])
        # decided once per run: the paper's scenario has none of them, and the loop asks at
        # every instant
        self.noisy = bool(np.any(self.noise_std > 0))
        self.mismatched = bool(np.any(self.gains != 1.0))
        self.mean_wind = np.asarray(disturbances.wind_mean_m_s, dtype=np.float64)
        self.calm = disturbances.gust_std_m_s == 0 and not np.any(self.mean_wind != 0.0)

    @property
    def wind(self) -> np.ndarray:
        """``(N, 2)`` wind velocity over the current period, m/s."""
        return self.mean_wind + self.gusts

    def measure(self, states: np.ndarray) -> np.ndarray:
        """``(N, 4)``: the states as the UAVs measure them (``states`` itself without noise)."""
        if not self.noisy:
            return states
        return states + self.noise_rng.normal(size=states.shape) * self.noise_std

    def step(self, states: np.ndarray, controls: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The plant's next states under ``controls`` (commanded), and the wind that acted."""
        timing, disturbances = self.scenario.timing, self.scenario.disturbances
        if self.mismatched:
            controls = controls * self.gains
        following = step_plant(states, controls, timing.period_s, timing.rk4_substeps)
        wind = self.wind
        if not self.calm:
            following[:, :2] += wind * timing.period_s
        if disturbances.gust_std_m_s > 0:
            decay = math.exp(-timing.period_s / disturbances.gust_time_constant_s)
            spread = disturbances.gust_std_m_s * math.sqrt(1.0 - decay * decay)
            self.gusts = decay * self.gusts + spread * self.wind_rng.normal(size=self.gusts.shape)
        return following, wind
