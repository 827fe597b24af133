"""The hybrid step 1: physics + a residual net behind a trust gate, streamed and batched."""

from __future__ import annotations

import copy
import dataclasses
import pickle

import numpy as np
import pytest
from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.estimator import compiled
from wrenchd.models.estimator import coverage as coverage_module
from wrenchd.models.estimator.coverage import Coverage, CoverageConfig, smoothstep
from wrenchd.models.estimator.estimator import TwoStepEstimator
from wrenchd.models.estimator import hybrid as hybrid_module
from wrenchd.models.estimator.hybrid import (
    HYBRID_PHYSICS,
    HybridConfig,
    HybridStep1,
    ResidualNetConfig,
    fit_hybrid,
)
from wrenchd.models.physics.dynamics import RigidBodyModel
from wrenchd.models.physics.least_squares import LeastSquaresConfig, RigidBodyFrictionModel
from wrenchd.models.series import JointStates

DT = 0.005
CENTRE = np.array([-0.2, 0.0, 0.15, 0.0, 0.0, 0.0])
AMPLITUDE = np.array([0.3, 0.4, 0.05, 0.6, 0.4, 0.4])


def trajectory(seconds: float, phase: float = 0.0, scale: float = 1.0) -> JointStates:
    """A smooth periodic excitation (period 4 s) with torques from a fixed rigid body +
    friction model plus a position-dependent effect that physics lacks."""
    t = np.arange(int(round(seconds / DT))) * DT
    w = 2 * np.pi / 4.0
    k = np.array([3.0, 2.0, 4.0, 5.0, 6.0, 7.0])
    arg = w * t[:, None] * k[None, :] / 2 + phase + k
    q = CENTRE + scale * AMPLITUDE * np.sin(arg)
    dq = scale * AMPLITUDE * (w * k / 2) * np.cos(arg)
    ddq = -scale * AMPLITUDE * (w * k / 2) ** 2 * np.sin(arg)
    rigid = RigidBodyModel()
    tau = rigid.inverse_dynamics(q, dq, ddq)
    tau += 0.05 * np.tanh(dq / 0.02) + 0.02 * dq
    ripple = np.sin(3 * np.pi * (q - CENTRE) / AMPLITUDE)  # 1.5 periods over the range
    tau[:, :3] += 0.08 * ripple[:, :3]                    # e.g. transmission ripple
    return JointStates(t, q, dq, tau)


@pytest.fixture(scope="module")
def trained() -> HybridStep1:
    config = HybridConfig(residual=ResidualNetConfig(hidden=(32, 32), epochs=30, lr=1e-2))
    return fit_hybrid([trajectory(16.0)], config)


def rmse(a, b):
    return np.sqrt(np.mean((a - b) ** 2, axis=0))


def test_residual_learns_where_physics_misses(trained):
    test = trajectory(8.0)                                # the trained trajectory again
    x = np.concatenate([test.position, test.velocity], 1)
    parts = trained.parts(x)
    # all inside the coverage: full trust, also where the net reaches past its targets' range
    assert parts.weight.min() == 1.0
    low, high = trained.residual.out_range
    assert ((parts.residual < low) | (parts.residual > high)).any()
    phys, hyb = rmse(parts.physics, test.effort), rmse(parts.torque, test.effort)
    # The ripple is about 0.057 N m RMS and physics has no column for it.
    assert np.all(phys[:3] > 0.03), phys
    assert np.all(hyb[:3] < 0.6 * phys[:3]), (hyb, phys)


def test_outside_the_coverage_physics_alone(trained):
    far = trajectory(4.0, phase=1.3, scale=0.5)           # other joint states entirely
    x = np.concatenate([far.position, far.velocity], 1)
    parts = trained.parts(x)
    assert np.all(trained.coverage_distance(x) > trained.config.coverage.outer_distance)
    assert parts.weight.max() == 0.0
    np.testing.assert_array_equal(parts.torque, parts.physics)


def test_streaming_matches_batch(trained):
    test = trajectory(3.0, phase=0.2)
    x = np.concatenate([test.position, test.velocity], 1)
    batch = trained.predict_sequence(x)
    state, rows = None, []
    for row in x:
        y, state = trained.step(row, state)
        rows.append(y)
    np.testing.assert_allclose(np.array(rows), batch, rtol=0, atol=1e-10)
    # Two streams at once, and a segment run in chunks.
    state2 = trained.initial_state(2)
    y2 = [trained.step(np.stack([r, r]), state2 := trained.step(np.stack([r, r]), state2)[1])[0]
          for r in x[:1]]
    assert y2[0].shape == (2, 6)
    a, s = trained.run(x[:100], trained.initial_state(1))
    b, _ = trained.run(x[100:], s)
    np.testing.assert_allclose(np.concatenate([a, b]), batch, rtol=0, atol=1e-10)


def test_the_compiled_step_is_the_numpy_step(trained):
    """Where numba is installed the streaming step runs compiled: the same torques as NumPy's
    to float64 rounding, for one stream and two, with every trust regime (inside the
    coverage, at its edge, outside it) and a fresh start in the middle."""
    pytest.importorskip("numba")
    near = trajectory(3.0, phase=0.2)
    edge = trajectory(3.0, phase=0.2, scale=1.15)
    x = np.concatenate([np.concatenate([s.position, s.velocity], 1) for s in (near, edge)])
    weight = trained.parts(x).weight
    assert weight.max() == 1.0 and weight.min() == 0.0 and ((weight > 0) & (weight < 1)).any()
    fast, slow = copy.copy(trained), copy.copy(trained)
    fast._compiled, slow._compiled = compiled.DEFERRED, None         # None: NumPy serves
    for streams in (1, 2):
        out = {}
        for name, model in (("fast", fast), ("slow", slow)):
            state, ys = None, []
            for k in range(len(x)):
                if k == len(near):
                    state = None                                      # a fresh start
                rows = np.stack([x[(k + 150 * b) % len(x)] for b in range(streams)])
                y, state = model.step(rows, state)
                ys.append(y)
            out[name] = np.array(ys)
        assert fast._compiled is not None
        np.testing.assert_allclose(out["fast"], out["slow"], rtol=1e-12,
                                   atol=1e-12 * np.abs(out["slow"]).max())
    # a daemon's passes: runs of a few rows, stepped compiled, and the NumPy run at once
    sizes = np.resize([1, 3, hybrid_module.STREAMED_ROWS, 2], len(x))
    cuts = np.cumsum(sizes)[np.cumsum(sizes) < len(x)]
    state, chunks = fast.initial_state(1), []
    for part in np.split(x, cuts):
        y, state = fast.run(part, state)
        chunks.append(y)
    whole, _ = slow.run(x, slow.initial_state(1))
    np.testing.assert_allclose(np.concatenate(chunks), whole, rtol=1e-10,
                               atol=1e-10 * np.abs(whole).max())


def test_a_pickled_or_copied_model_streams_as_the_original(trained):
    """A model sent to another process (pickled) or deep-copied leaves its compiled step
    behind and builds its own: it streams the same torques."""
    test = trajectory(1.0, phase=0.4)
    x = np.concatenate([test.position, test.velocity], 1)
    trained.kernel()
    want, _ = trained.run(x, trained.initial_state(1))
    for other in (pickle.loads(pickle.dumps(trained)), copy.deepcopy(trained)):
        state, rows = None, []
        for row in x:
            y, state = other.step(row, state)
            rows.append(y)
        np.testing.assert_allclose(np.array(rows), want, rtol=0, atol=1e-10)


def test_a_state_of_another_shape_is_refused(trained):
    """The compiled step reads its state without bounds checks: a state for other streams
    or another filter is refused with a clear error before it gets there."""
    row = np.concatenate([CENTRE, np.zeros(6)])
    history, started, follower = trained.initial_state(2)
    for bad in ((history, started, follower),                      # two streams, one row
                (history[:1, :-1], started[:1], follower[:1]),       # a shorter filter
                (history[:1], started, follower[:1])):
        with pytest.raises(DataError, match="state"):
            trained.step(row, bad)


def test_two_streams_step_independently(trained):
    one, two = trajectory(1.0), trajectory(1.0, phase=0.7)
    x1 = np.concatenate([one.position, one.velocity], 1)
    x2 = np.concatenate([two.position, two.velocity], 1)
    state, out = trained.initial_state(2), []
    for r1, r2 in zip(x1, x2):
        y, state = trained.step(np.stack([r1, r2]), state)
        out.append(y)
    out = np.array(out)
    np.testing.assert_allclose(out[:, 0], trained.predict_sequence(x1), atol=1e-10)
    np.testing.assert_allclose(out[:, 1], trained.predict_sequence(x2), atol=1e-10)


def test_serves_as_step1_of_the_two_step_estimator(trained):
    test = trajectory(2.0)
    est = TwoStepEstimator(trained)
    streamed = np.array([est.step_one(t, q, dq, tau).predicted_torque for t, q, dq, tau in
                         zip(test.t, test.position, test.velocity, test.effort)])
    batch = est.predict_batch(test)
    np.testing.assert_allclose(streamed, batch.predicted_torque, atol=1e-10)
    np.testing.assert_allclose(batch.predicted_torque, trained.predict_series(test), atol=1e-12)
    est.reset_state()
    many = est.step_many(test.t, test.position, test.velocity, test.effort)
    np.testing.assert_allclose(np.array([o.predicted_torque for o in many]), streamed,
                               atol=1e-10)


def test_a_corr_trains_on_the_hybrid_and_removes_a_set_up_torque(trained):
    """Step 2 on a hybrid step 1: a constant torque the free-space data never had (as a
    cannula seal adds) is learned by a Corr trained offline, and the pipeline's lifelong
    adaptation runs on it (its step 1 has no torch normalisation: the adapter fits one)."""
    from wrenchd.models.estimator.correction_training import fit_corr
    from wrenchd.models.estimator.training import recipe
    from wrenchd.service.pipeline import ArmPipeline, PipelineConfig

    base = trajectory(12.0, phase=0.3)
    offset = np.array([0.15, -0.1, 0.4, 0.0, 0.0, 0.0])   # [N m, N m, N, ...]
    seal = JointStates(base.t, base.position, base.velocity, base.effort + offset)
    result = fit_corr(trained, [seal], config=recipe("corr-fast"))
    est = TwoStepEstimator(trained, result.model)
    test = JointStates(*(a[-400:] for a in (seal.t, seal.position, seal.velocity,
                                           seal.effort)))
    before = rmse(trained.predict_series(test), test.effort)
    after = rmse(est.predict_batch(test).predicted_torque, test.effort)
    # step 2 learns the seal offset: each of joints 1-3 gains, and together they lose over half
    # of the error step 1 leaves (bounds loose enough for the training's spread)
    assert np.all(after[:3] < 0.85 * before[:3]) and after[:3].sum() < 0.5 * before[:3].sum(), \
        (after, before)
    p = ArmPipeline("PSM1", trained, PipelineConfig(calibration_s=1.0))
    assert p.backend.adapter.normalisation is None
    from wrenchd.models.series import JointSample
    for k in range(len(test)):
        p.process(JointSample(int(round(test.t[k] * 1e9)), "", (), test.position[k],
                              test.velocity[k], test.effort[k]))
    assert p.counters.estimated == len(test) and p.counters.offered > 0


def test_a_residual_past_its_training_range_is_not_trusted(trained):
    """Inside the range of its targets the residual keeps its trust; a quarter of the range's
    width beyond it (``residual_range_margin``), none, smoothly between; where one joint
    leaves, the whole sample's trust goes. Without a margin or a range: no bound."""
    low, high = trained.residual.out_range
    width = high - low
    res = np.tile((low + high) / 2, (5, 1))
    res[1] = high                                  # at the edge
    res[2, 0] = high[0] + 0.125 * width[0]         # half the margin out, one joint
    res[3, 2] = low[2] - 0.25 * width[2]           # the margin out
    res[4, 1] = high[1] + 10 * width[1]
    trust = trained.residual.range_trust(res, 0.25)
    np.testing.assert_allclose(trust, [1.0, 1.0, 0.5, 0.0, 0.0], atol=1e-12)
    assert trained.residual.range_trust(res, None) is None
    unbounded = dataclasses.replace(trained.residual, out_range=None)
    assert unbounded.range_trust(res, 0.25) is None


def test_half_the_speed_is_inside_the_coverage_but_past_the_range():
    """The trained trajectory at half its speed (a quarter of its accelerations): the
    residual is asked about velocities and accelerations it never saw, and the coverage, in
    doubt there, still half-trusts it; the range bound takes that trust back."""
    config = HybridConfig(residual=ResidualNetConfig(hidden=(32, 32), epochs=30, lr=1e-2))
    model = fit_hybrid([trajectory(16.0)], config)
    free = fit_hybrid([trajectory(16.0)], config.model_copy(update={"residual_range_margin": None}))
    t = np.arange(int(8.0 / DT)) * DT
    slow = trajectory(16.0)
    x = np.concatenate([slow.position[::2][:len(t)], slow.velocity[::2][:len(t)] / 2], 1)
    bounded, unbounded = model.parts(x), free.parts(x)
    np.testing.assert_array_equal(bounded.residual, unbounded.residual)
    assert bounded.weight.sum() < 0.9 * unbounded.weight.sum()
    assert np.all(bounded.weight <= unbounded.weight)
    # the bound only acts where the coverage doubts: w (1 - (1 - w)(1 - range trust))
    w, r = unbounded.weight, model.residual.range_trust(bounded.residual, 0.25)
    np.testing.assert_allclose(bounded.weight, w * (1 - (1 - w) * (1 - r)), atol=1e-12)
    assert np.all(bounded.weight[w == 1.0] == 1.0)


def test_save_and_load(trained, tmp_path):
    path = tmp_path / "hybrid.pt"
    trained.save(path)
    loaded = HybridStep1.load(path)
    test = trajectory(2.0, phase=0.4)
    x = np.concatenate([test.position, test.velocity], 1)
    np.testing.assert_array_equal(loaded.predict_sequence(x), trained.predict_sequence(x))
    assert loaded.config == trained.config and loaded.info == trained.info
    np.testing.assert_array_equal(loaded.residual.out_range, trained.residual.out_range)
    # a model saved before the range bound existed loads, and has none
    arrays = {k: v for k, v in trained.arrays().items() if k != "out_range"}
    older = HybridStep1.from_parts(arrays, trained.description())
    assert older.residual.out_range is None
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a model")
    with pytest.raises(ConfigError):
        HybridStep1.load(bad)


def test_bad_input(trained):
    with pytest.raises(DataError):
        trained.predict_sequence(np.zeros((10, 11)))
    with pytest.raises(DataError):
        trained.step(np.full(12, np.nan))
    with pytest.raises(DataError):
        fit_hybrid([])
    fast = trajectory(1.0)
    with pytest.raises(DataError, match="trained at"):
        trained.predict_series(JointStates(fast.t / 5, fast.position, fast.velocity,
                                           fast.effort))


def test_coverage_weight():
    x = np.zeros((5, 12))
    x[:, 0] = np.linspace(0.0, 4.0, 5)
    cov = Coverage.fit([x], CoverageConfig(inner_distance=0.5, outer_distance=1.0, stride=1))
    # Normalised: feature 0 has std sqrt(2), the other features never move.
    probe = np.zeros((3, 12))
    probe[:, 0] = [2.0, 2.0 + 0.75 * np.sqrt(2), 2.0 + 2.0 * np.sqrt(2)]
    probe[1:, 0] += 2.0                                   # beyond the last training row
    np.testing.assert_allclose(cov.distance(probe), [0.0, 0.75, 2.0], atol=1e-12)
    np.testing.assert_allclose(cov.weight(probe), [1.0, 0.5, 0.0])
    assert smoothstep(np.array([-1.0, 0.5, 2.0])).tolist() == [0.0, 0.5, 1.0]
    with pytest.raises(ValueError):
        CoverageConfig(inner_distance=1.0, outer_distance=0.5)


def test_coverage_of_a_few_rows_is_the_tree_s_nearest_distance():
    """A streamed row is measured against every point, a batch searched in the tree: the same
    distances either way, near the points and far from them."""
    rng = np.random.default_rng(4)
    cov = Coverage.fit([rng.normal(size=(3000, 18))], CoverageConfig(acceleration_weight=0.3))
    probe = np.concatenate([cov.points[:40] * cov.scale + cov.mean
                            + rng.normal(scale=0.05, size=(40, 18)),
                            rng.normal(scale=3.0, size=(40, 18))])
    searched = cov.distance(probe)                            # 80 rows: the tree
    assert len(probe) > coverage_module.BRUTE_ROWS
    one_by_one = np.concatenate([cov.distance(row[None]) for row in probe])
    np.testing.assert_allclose(one_by_one, searched, rtol=1e-9, atol=1e-9)
    assert searched[:40].max() < 0.5 < searched[40:].min()   # both regimes were probed


def test_coverage_with_accelerations_weighs_them_and_keeps_old_rows():
    """An 18-column coverage scales the accelerations' distance by the weight; a 12-column
    one (as older hybrid files hold) still measures [q, dq] only."""
    x = np.zeros((5, 18))
    x[:, 12] = np.linspace(0.0, 4.0, 5)                  # one acceleration, std sqrt 2
    cov = Coverage.fit([x], CoverageConfig(acceleration_weight=0.5, stride=1))
    probe = np.zeros((1, 18))
    probe[0, 12] = 4.0 + 2.0 * np.sqrt(2)
    np.testing.assert_allclose(cov.distance(probe), [1.0], atol=1e-12)     # 2.0 * 0.5
    assert cov.width == 18
    with pytest.raises(DataError, match=r"\(N, 18\)"):
        cov.distance(np.zeros((1, 12)))
    with pytest.raises(DataError, match="acceleration_weight"):
        Coverage.fit([x], CoverageConfig())
    assert Coverage.fit([x[:, :12]], CoverageConfig()).width == 12


def test_physics_is_the_least_squares_model(trained):
    assert isinstance(trained.physics, RigidBodyFrictionModel)
    assert trained.info["physics_rank"] == trained.physics.rank


def test_causal_the_future_does_not_change_the_past(trained):
    """Acceleration filter and presliding state alike read only past samples."""
    assert trained.config.physics == HYBRID_PHYSICS
    assert trained.physics.config.hysteresis_width is not None
    test = trajectory(3.0, phase=0.5)
    x = np.concatenate([test.position, test.velocity], 1)
    changed = x.copy()
    changed[300:, :6] += 0.02                                 # other future positions ...
    changed[300:, 6:] *= -1.0                                 # ... and velocities
    before, after = trained.predict_sequence(x), trained.predict_sequence(changed)
    np.testing.assert_array_equal(after[:300], before[:300])
    assert not np.allclose(after[300:], before[300:])


def test_a_model_without_presliding_columns_saves_loads_and_streams(tmp_path):
    """The columns of the plain least-squares default (as hybrid files written before the
    presliding column have them): fitted, saved, loaded, streamed."""
    config = HybridConfig(physics=LeastSquaresConfig(),
                          residual=ResidualNetConfig(hidden=(8,), epochs=2))
    plain = fit_hybrid([trajectory(6.0)], config)
    assert plain.physics.coefficients.shape == (90,)
    test = trajectory(1.0, phase=0.4)
    x = np.concatenate([test.position, test.velocity], 1)
    description = plain.description()
    for physics_config in (description["config"]["physics"], description["physics"]["config"]):
        del physics_config["hysteresis_width"]                # as an older file has it
    loaded = HybridStep1.from_parts(plain.arrays(), description)
    assert loaded.config == plain.config
    np.testing.assert_array_equal(loaded.predict_sequence(x), plain.predict_sequence(x))
    path = tmp_path / "plain.pt"
    plain.save(path)
    from_file, state, rows = HybridStep1.load(path), None, []
    for row in x:
        y, state = from_file.step(row, state)
        rows.append(y)
    np.testing.assert_allclose(np.array(rows), plain.predict_sequence(x), atol=1e-10)
