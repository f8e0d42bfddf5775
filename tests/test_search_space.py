"""The search space of ``covviz tune``, declared next to ManifoldConfig (no Optuna needed)."""

from __future__ import annotations

import pytest

from covviz.trackers.manifold import (
    SEARCH_SPACE,
    ManifoldConfig,
    config_from_params,
    search_params,
    suggest_config,
)


class FakeTrial:
    """Answers every suggest_* with the low (or high) end of its range, and records the calls."""

    def __init__(self, end: str = "low"):
        self.end = end
        self.calls: dict[str, tuple] = {}

    def suggest_float(self, name, low, high, log=False):
        self.calls[name] = ("float", low, high, log)
        return low if self.end == "low" else high

    def suggest_int(self, name, low, high):
        self.calls[name] = ("int", low, high)
        return low if self.end == "low" else high


def test_every_range_is_valid_and_holds_the_default():
    defaults = search_params()
    assert set(defaults) == set(SEARCH_SPACE)
    for name, (low, high, scale) in SEARCH_SPACE.items():
        assert scale in ("log", "linear", "int"), name
        assert low < high and (scale != "log" or low > 0), name
        assert low <= defaults[name] <= high, f"{name}: the default {defaults[name]} is outside [{low}, {high}]"


@pytest.mark.parametrize("end", ["low", "high"])
def test_every_corner_of_the_space_is_a_valid_config(end):
    trial = FakeTrial(end)
    cfg = suggest_config(trial)
    assert isinstance(cfg, ManifoldConfig)
    assert set(trial.calls) == set(SEARCH_SPACE)
    assert all(c[3] == (SEARCH_SPACE[n][2] == "log") for n, c in trial.calls.items() if c[0] == "float")
    got = search_params(cfg)
    assert got == {n: (lo if end == "low" else hi) for n, (lo, hi, _) in SEARCH_SPACE.items()}


def test_config_from_params_sets_nested_fields_and_keeps_the_base():
    base = ManifoldConfig().replace(n_particles=50, quadrants=False)
    cfg = config_from_params({"kinematics.pos_sigma.0": 0.07, "likelihood_sigma": 0.8}, base)
    assert cfg.kinematics.pos_sigma == (0.07, base.kinematics.pos_sigma[1])
    assert cfg.observation.likelihood_sigma == 0.8 and cfg.n_particles == 50 and cfg.observation.quadrants is False
    assert config_from_params(search_params(base), base) == base
    with pytest.raises(ValueError, match="unknown ManifoldConfig parameter 'nope'"):
        config_from_params({"nope": 1.0})
    with pytest.raises(ValueError, match="likelihood_sigma must be a number > 0"):
        config_from_params({"likelihood_sigma": 0.0})
