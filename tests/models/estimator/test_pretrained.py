"""The shipped step-1 weights: they load safely and predict fresh simulated free motion."""

import numpy as np
import pytest

from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.estimator.pretrained import PRETRAINED, load_pretrained, pretrained_path


#: The scenario each shipped model is checked on: a fresh 30 s session (seed 777, never
#: trained on), scored as RMSE / torque std per joint. The bounds leave room for a retrained
#: model and fail a broken one, whose ratio is about 1 or more.
SCENARIO = {"base": "free-space", "seal": "free-space-seal"}

@pytest.mark.parametrize("name", PRETRAINED)
def test_pretrained_predicts_fresh_free_motion(name):
    path = pretrained_path(name)
    assert path.is_file() and path.stat().st_size < 2_500_000
    model = load_pretrained(name)
    assert isinstance(model, FreeSpaceModel) and not model.training
    js = run_scenario(SCENARIO[name], 30.0, 777).joint_states
    pred = model.predict_sequence(np.concatenate([js.position, js.velocity], axis=1))
    ratio = np.sqrt(np.mean((pred - js.effort) ** 2, axis=0)) / js.effort.std(axis=0)
    assert np.all(ratio < 0.8), ratio
    assert ratio.mean() < 0.4, ratio

def test_unknown_pretrained_name():
    with pytest.raises(ConfigError, match="unknown pretrained"):
        load_pretrained("trocar")
    with pytest.raises(ConfigError):
        pretrained_path("")
