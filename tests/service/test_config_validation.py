"""Every configuration names a bad value when it is built or loaded, before any sample: a
wrong length, a value out of range, or two fields that contradict each other."""

import pytest
from pydantic import ValidationError

from wrenchd.models.adaptation.config import AdaptationConfig
from wrenchd.models.body_wall_tracker import BodyWallTrackerConfig
from wrenchd.models.drift_detector import DriftConfig
from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.correction import CorrConfig, XferConfig
from wrenchd.models.estimator.coverage import CoverageConfig
from wrenchd.models.estimator.estimator import EstimatorConfig
from wrenchd.models.estimator.free_space import FreeSpaceConfig
from wrenchd.models.estimator.hybrid import HybridConfig, ResidualNetConfig
from wrenchd.models.estimator.training import TrainConfig
from wrenchd.models.estimator.wrench import WrenchMapConfig
from wrenchd.models.identification.excitation import ExcitationConfig
from wrenchd.models.physics.causal_acceleration import CausalAccelerationConfig
from wrenchd.models.physics.dynamics import LinkInertia, RigidBodyConfig
from wrenchd.models.physics.least_squares import LeastSquaresConfig
from wrenchd.models.physics.model import EffectSpec, PhysicsModelConfig
from wrenchd.service.runtime.settings import (
    ArmConfig,
    CpuPlacement,
    KeysConfig,
    RingConfig,
    RosSettings,
    ServiceSettings,
    SimulatorSettings,
    load_settings,
)
from wrenchd.service.studies.reproduction_config import ReproductionConfig, Step1Training

CASES = [
    # (config, bad fields, a part of the message that names the value)
    (AdaptationConfig, {"recent_fraction": 1.5}, "recent_fraction"),
    (AdaptationConfig, {"min_train_samples": 900, "recent_size": 400, "reservoir_size": 0},
     r"min_train_samples \(900\) exceeds"),
    (BodyWallTrackerConfig, {"incision_m": (0.0, 0.0)}, "incision_m"),
    (DriftConfig, {"adwin_delta": 1.0}, "adwin_delta"),
    (EstimatorConfig, {"max_jump": (0.05,) * 5}, "max_jump"),
    (EstimatorConfig, {"max_jump": (0.05, 0.05, 0.0, 0.1, 0.1, 0.1)}, "jump must be > 0"),
    (WrenchMapConfig, {"threshold": 0.0}, "threshold"),
    (FreeSpaceConfig, {"seal_groups": (7,)}, "seal_groups must be distinct indices"),
    (CorrConfig, {"window": 0}, "window"),
    (XferConfig, {"dropout": 1.0}, "dropout"),
    (ResidualNetConfig, {"hidden": (128, 0)}, "at least one unit"),
    (CoverageConfig, {"inner_distance": 2.0}, "outer_distance must exceed"),
    (HybridConfig, {"max_gap_s": -1.0}, "max_gap_s"),
    (TrainConfig, {"val_fraction": 1.0}, "val_fraction"),
    (CausalAccelerationConfig, {"groups": ((0, 1), (2,))}, "partition"),
    (LeastSquaresConfig, {"hysteresis_width": (0.01,) * 5}, "hysteresis_width"),
    (LinkInertia, {"mass_kg": -1.0, "com_m": (0, 0, 0), "inertia_kgm2": (0,) * 6}, "mass_kg"),
    (RigidBodyConfig, {"armature": (0.1,) * 5}, "armature"),
    (EffectSpec, {"name": "seal_frict"}, "unknown effect"),
    (PhysicsModelConfig, {"effects": [{"name": "seal_friction"}, {"name": "seal_friction"}]},
     "repeated"),
    (ExcitationConfig, {"hold": (0.0,) * 6, "joints": (1, 1)}, "joints must be distinct"),
    (KeysConfig, {"events": "a/*/b"}, "events"),
    (RosSettings, {"domain_id": 300}, "domain_id"),
    (ArmConfig, {"encoding": "xml"}, "encoding"),
    (SimulatorSettings, {"scenario": "trocar-contakt"}, "unknown scenario 'trocar-contakt'"),
    (RingConfig, {"capacity": 0}, "capacity"),
    (CpuPlacement, {"realtime_priority": 120}, "SCHED_FIFO priority"),
    (ServiceSettings, {"arms": [{"name": "PSM1"}, {"name": "PSM1"}]}, "unique"),
    (Step1Training, {"overrides": {"window": 1}}, "recipe 'free-space': window"),
    (ReproductionConfig, {"lengths_s": (40.0, 20.0)}, "lengths_s must be positive"),
]


@pytest.mark.parametrize("config, bad, named", CASES,
                         ids=[f"{c.__name__}-{'-'.join(b)}" for c, b, _ in CASES])
def test_a_bad_value_is_named_when_the_config_is_built(config, bad, named):
    with pytest.raises(ValidationError, match=named):
        config(**bad)


@pytest.mark.parametrize("toml, named", [
    ('[simulator]\nscenario = "trocar-contakt"\n', "simulator.scenario: .*trocar-contakt"),
    ('[[arms]]\nname = "PSM1"\n[arms.pipeline.adaptation]\nmin_train_samples = 20000\n',
     "arms.0.pipeline.adaptation: .*min_train_samples"),
    ('[[arms]]\nname = "PSM1"\n[arms.pipeline.drift]\nblock = 0\n',
     "arms.0.pipeline.drift.block"),
])
def test_a_bad_value_in_the_settings_file_is_named_at_load(tmp_path, toml, named):
    path = tmp_path / "bad.toml"
    path.write_text(toml)
    with pytest.raises(ConfigError, match=named):
        load_settings(path)


def test_wrenchd_config_refuses_a_bad_file_by_name(tmp_path, capsys):
    from wrenchd.service.cli import main

    path = tmp_path / "bad.toml"
    path.write_text('[ring]\ncapacity = 0\n')
    assert main(["config", "--config", str(path)]) == 2
    assert "ring.capacity" in capsys.readouterr().err
