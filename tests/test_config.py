"""Tests of the declarative config validation (:mod:`covviz.config`): one table of types and ranges per config."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from covviz.config import ConfigError, Spec, as_plain, check, from_mapping
from covviz.diagnosis.drift import DIAGNOSIS_SPECS, DiagnosisConfig
from covviz.model.dynamics import KINEMATIC_SPECS, KinematicModel
from covviz.model.observation import OBSERVATION_SPECS, ObservationConfig
from covviz.trackers.manifold import MANIFOLD_SPECS, ManifoldConfig


@pytest.mark.parametrize(
    ("cls", "specs"),
    [(ManifoldConfig, MANIFOLD_SPECS), (ObservationConfig, OBSERVATION_SPECS), (KinematicModel, KINEMATIC_SPECS),
     (DiagnosisConfig, DIAGNOSIS_SPECS)],
)
def test_every_field_has_a_spec_and_every_default_passes_it(cls, specs):
    assert {f.name for f in dataclasses.fields(cls)} == set(specs)
    check(cls(), specs)  # the defaults are valid


@pytest.mark.parametrize(
    ("spec", "good", "bad"),
    [
        (Spec("bool"), [True, False, np.bool_(True)], ["false", 0, 1, None, 1.0]),
        (Spec("int", 2, 10), [2, 10, np.int64(5)], [1, 11, 2.5, True, "3"]),
        (Spec("float", 0, 1, lo_open=True), [1e-9, 0.5, 1, 1.0], [0, -1, 1.1, float("nan"), float("inf"), True]),
        (Spec("str", choices=("a", "b")), ["a", "b"], ["c", 1, None]),
        (Spec("pair", 0), [(0.0, 1.0), [1, 2]], [(1.0,), (1, -1), (1, float("nan")), 3]),
        (Spec("float", optional=True), [None, 1.5], ["x"]),
    ],
)
def test_a_spec_takes_exactly_its_values(spec, good, bad):
    from covviz.config import _ok

    assert all(_ok(v, spec) for v in good)
    assert not any(_ok(v, spec) for v in bad)


def test_errors_name_the_config_and_the_field_in_one_line():
    with pytest.raises(ConfigError) as e:
        ObservationConfig(quadrants="false")
    msg = str(e.value)
    assert msg == "ObservationConfig.quadrants must be true or false, got 'false'"
    with pytest.raises(ConfigError, match=r"^KinematicModel.velocity_decay must be a number in \[0, 1\], got 2$"):
        KinematicModel(velocity_decay=2)
    assert issubclass(ConfigError, ValueError)  # callers that catch ValueError still do


def test_from_mapping_nests_flat_keys_and_refuses_both_or_unknown():
    c = ManifoldConfig.from_dict({"quadrants": False, "n_particles": 50, "kinematics": {"pos_sigma": [0.1, 0.3]}})
    assert c.observation.quadrants is False and c.n_particles == 50 and c.kinematics.pos_sigma == (0.1, 0.3)
    assert ManifoldConfig.from_dict(c.as_dict()) == c  # nested round trip
    with pytest.raises(ConfigError, match="given both flat and inside 'observation'"):
        ManifoldConfig.from_dict({"quadrants": False, "observation": {"quadrants": True}})
    with pytest.raises(ConfigError, match="unknown ObservationConfig field"):
        ManifoldConfig.from_dict({"observation": {"quadrantz": True}})
    with pytest.raises(ConfigError, match="must be a JSON object"):
        from_mapping(ObservationConfig, [1, 2], OBSERVATION_SPECS)


def test_replace_routes_flat_observation_names():
    c = ManifoldConfig().replace(quadrants=False, n_particles=30, colour_weight=0.0)
    assert (c.observation.quadrants, c.observation.colour_weight, c.n_particles) == (False, 0.0, 30)
    assert c.observation.patch_size == ObservationConfig().patch_size  # the rest untouched


def test_as_plain_is_json_ready():
    import json

    d = as_plain(ManifoldConfig())
    assert json.loads(json.dumps(d)) == d and isinstance(d["kinematics"]["pos_sigma"], list)
