"""The pipeline's settings: validation bounds, the adaptation policy, the calibration guard."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from wrenchd.models.adaptation import AdaptationConfig
from wrenchd.models.drift_detector import DriftConfig
from wrenchd.models.estimator.estimator import EstimatorConfig
from wrenchd.models.gate import GateConfig
from wrenchd.service.pipeline.mechanisms import MECHANISMS

POLICIES = tuple(MECHANISMS)


class ValidationConfig(BaseModel):
    """What a joint state must satisfy to be estimated."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    max_abs_position: tuple[float, ...] = Field(
        default=(3.2, 3.2, 0.5, 5.0, 3.2, 3.2),
        description="|q| bound per joint [rad; m on insertion]; beyond is refused")
    max_abs_velocity: tuple[float, ...] = Field(
        default=(10.0, 10.0, 2.0, 20.0, 20.0, 20.0), description="|dq| bound [rad/s; m/s]")
    max_abs_effort: tuple[float, ...] = Field(
        default=(50.0, 50.0, 200.0, 10.0, 10.0, 10.0), description="|effort| bound [N m; N]")
    resync_after: int = Field(
        default=40, ge=1,
        description="this many consecutive samples stamped before the last accepted one mean "
                    "the publisher's clock restarted (or one stamp came from the far future): "
                    "accept the new timeline ('clock_reset' event) instead of refusing forever")
    setup_ahead_s: float = Field(
        default=5.0, ge=0.0,
        description="a set-up change notice stamped further than this after the arm's latest "
                    "sample is refused: its clock is not the robot's (a wall-clock stamp on a "
                    "robot stamping from its start would keep adaptation eager for ever) [s]")


class PolicyConfig(BaseModel):
    """Which samples reach the adaptation, and when it may run."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: Literal["gated", "ungated", "frozen", "drift-triggered", "periodic-reset"] = "gated"
    release_delay_s: float = Field(default=2.5, ge=0.0,
                                   description="a free sample waits this long for a contact [s]")
    onset_margin_s: float = Field(
        default=2.5, ge=0.0,
        description="when a contact is found, the waiting samples from this long before the "
                    "gate's onset on are dropped (the force builds up under the bound first: "
                    "the gate finds some contacts seconds after they start); older ones go "
                    "on waiting and are offered after the contact [s]")
    reset_every_s: float = Field(default=120.0, gt=0.0,
                                 description="periodic-reset: back to the initial net [s]")


class CalibrationGuardConfig(BaseModel):
    """The check that the calibration is contact-free (see :class:`ArmPipeline` and
    :mod:`wrenchd.service.pipeline.calibration`).

    The step-1 residual (measured minus step-1 torque) does not change while the correction
    net calibrates, and the step-1 model's held-out (validation) RMSE says how large it is in
    free motion; a contact adds ``J^T w`` on top. So a :class:`FreeMotionGate` on it, seeded
    with ``scale_factor`` x that RMSE instead of a warm-up (a warm-up could itself be spent in
    contact: a contact may begin within a session's first seconds), can judge from the first
    sample; from 2 s into the window on, its scale follows ``robust_factor`` x the robust
    level of the window's residual (within ``max_growth`` x the seeded scale on the joints
    the model fits). It keeps what it calls contact out of training through the gated phase's
    delay line (``action: refuse``), or only counts and warns (``action: warn``). A
    joint whose lower-quartile residual level is over ``mismatch_ratio`` x its held-out RMSE
    says the model does not fit the arm (a ``model_mismatch`` event and the status).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    enabled: bool = Field(default=True, description="judge the calibration's samples")
    action: Literal["warn", "refuse"] = Field(
        default="refuse",
        description="refuse: what the guard calls contact does not train (nor do the "
                    "samples the delay line drops around it), and the guard's free flag is "
                    "published during the calibration; warn: every calibration sample "
                    "trains, contact included, the guard only counts and warns (all free)")
    residual_scale: tuple[float, ...] | None = Field(
        default=None,
        description="free-motion RMS of the step-1 residual per joint [N m; N on insertion]; "
                    "None: the step-1 checkpoint's validation RMSE (no guard when unknown)")
    scale_factor: float = Field(
        default=2.0, gt=0.0,
        description="the guard starts from this x residual_scale (a set-up adds residual the "
                    "step-1 validation did not have: at 1.0 the guard calls much of a "
                    "contact-free calibration contact)")
    robust_factor: float = Field(
        default=1.5, gt=0.0,
        description="the guard's scale follows this x the window's robust residual level "
                    "(1.4826 x the median |residual| per joint), not below the seeded scale")
    mismatch_ratio: float = Field(
        default=15.0, gt=1.0,
        description="a joint whose lower-quartile residual level over the calibration window "
                    "(as a normal RMS) is more than this x its held-out RMSE (floored by the "
                    "gate's min_std): the step-1 model does not fit the arm there "
                    "('model_mismatch' event, status), and the guard's scale on that joint "
                    "follows the window's level")
    follow_ratio: float = Field(
        default=3.0, gt=1.0,
        description="a joint whose fit ratio (as for mismatch_ratio) is over this: the guard's "
                    "scale there follows the window's level without the max_growth bound, "
                    "which would hold it under about two thirds of that level (motion or a "
                    "set-up the step-1 model never saw: the residual step 2 is there to learn "
                    "would otherwise be called contact and kept from it)")
    borderline_trains: bool = Field(
        default=True,
        description="refuse: a sample the guard calls free but over the gate's train_sigma "
                    "trains all the same (the calibration is there to learn the residual the "
                    "step-1 model leaves, its largest parts included)")
    gate_prior_s: float = Field(
        default=30.0, ge=0.0,
        description="refuse: when the calibration ends, the free-motion gate warms up again "
                    "with its scale kept within 1 and its max_growth times the RMS of the "
                    "residual over the samples the guard called free in the calibration's "
                    "last gate_prior_s [s] (a warm-up of a few seconds that falls on a contact "
                    "would start the gate several times too wide); 0, or fewer such samples "
                    "than the gate's warm-up: the warm-up alone")
    judge_warmup: bool = Field(
        default=True,
        description="refuse: with that prior, a second gate, started from scale_factor x "
                    "the prior, judges the gate's warm-up after the calibration beside the "
                    "guard, on the residual the correction net leaves: a sample is contact "
                    "where it calls it, and where the guard does (see warmup_confirm; the "
                    "guard alone judges the raw step-1 residual, where a trocar's force can "
                    "hide a contact)")
    warmup_confirm: bool = Field(
        default=False,
        description="judge_warmup: a contact the guard calls in the gate's warm-up is "
                    "published only while the second gate calls it too (from the guard's "
                    "onset); before, its samples are published free and train nothing (the "
                    "raw step-1 residual the guard judges swings at reversals the correction "
                    "net has learnt). Fewer false alarms after the calibration, contacts "
                    "begun in the warm-up flagged about 0.1 s later (docs/results.md)")
    warn_fraction: float = Field(
        default=0.3, ge=0.0, le=1.0,
        description="a calibration whose samples the guard called contact more than this "
                    "fraction ends with a 'calibration_contaminated' event")


class PipelineConfig(BaseModel):
    """Everything one arm's pipeline needs besides its networks."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    estimator: EstimatorConfig = Field(default_factory=EstimatorConfig)
    validation: ValidationConfig = Field(default_factory=ValidationConfig)
    gate: GateConfig = Field(default_factory=GateConfig)
    drift: DriftConfig = Field(default_factory=DriftConfig)
    adaptation: AdaptationConfig = Field(default_factory=AdaptationConfig)
    policy: PolicyConfig = Field(default_factory=PolicyConfig)
    calibration_s: float = Field(default=60.0, ge=0.0,
                                 description="contact-free calibration at the start [s]")
    calibration_guard: CalibrationGuardConfig = Field(default_factory=CalibrationGuardConfig)
