"""Shared simulated data and trained models for the estimator tests (built once per session)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.models.estimator.correction import Corr, Xfer
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.estimator.correction_training import fit_corr
from wrenchd.models.estimator.free_space_training import fit_free_space
from wrenchd.models.estimator.training import recipe

#: Small but real training budgets: the paper's structure (128-unit LSTMs, 256-unit Corr),
#: a handful of epochs.
FREE_SPACE_TEST_RECIPE = recipe("free-space", epochs=8, window=50, lane_windows=4,
                                batch_size=8, lr=3e-3, patience=None)
CORR_TEST_RECIPE = recipe("corr", epochs=6, batch_size=256)


@pytest.fixture(scope="session")
def free_space_session():
    return run_scenario("free-space", 60.0, 1)


@pytest.fixture(scope="session")
def trocar_train_sessions():
    # Eight short trajectories (4 min, the paper's intra-operative budget): one trajectory
    # alone lets the correction net memorise positions instead of learning the seal.
    return [run_scenario("trocar", 30.0, 10 + k) for k in range(8)]


@pytest.fixture(scope="session")
def trocar_held_out():
    return run_scenario("trocar", 30.0, 99)


@pytest.fixture(scope="session")
def trained_free_space(free_space_session):
    return fit_free_space([free_space_session.joint_states], config=FREE_SPACE_TEST_RECIPE,
                          data={"source": "sim", "scenario": "free-space", "seed": 1})


@pytest.fixture(scope="session")
def trained_corr(trained_free_space, trocar_train_sessions):
    return fit_corr(trained_free_space.model, [s.joint_states for s in trocar_train_sessions],
                    config=CORR_TEST_RECIPE,
                    data={"source": "sim", "scenario": "trocar", "seeds": list(range(10, 18))})


def _random_models(session, dtype, seed: int = 0):
    """Untrained step-1, Corr and Xfer models with normalisation fitted to ``session``."""
    js = session.joint_states
    x = np.concatenate([js.position, js.velocity], axis=1)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        fs = FreeSpaceModel().to(dtype)
        fs.set_input_normalisation(x)
        fs.set_output_normalisation(js.effort)
        corr = Corr().to(dtype)
        corr.set_normalisation(x, js.effort)
        xfer = Xfer(base=fs)
    return fs.eval(), corr.eval(), xfer.eval()


@pytest.fixture(scope="session")
def models_f64(free_space_session):
    """(FreeSpaceModel, Corr, Xfer), untrained, float64."""
    return _random_models(free_space_session, torch.float64)


@pytest.fixture(scope="session")
def models_f32(free_space_session):
    """(FreeSpaceModel, Corr, Xfer), untrained, float32."""
    return _random_models(free_space_session, torch.float32)
