"""The simulated PSM: prescribed smooth motion, physics model, sensors.

The dVRK PSM is position controlled with stiff joint servos, so wrenchd simulates it as a
perfect tracking controller: the joints follow the trajectory and the measured effort is the
torque that motion requires, ``tau = RNEA(q, dq, ddq) + sum(effects) + noise``. Effects with
memory (the seal's bristle state, anything a drift makes stateful) are integrated at the
internal step (1 kHz by default); memoryless terms are pure functions of the state, so they are
evaluated at the published samples only, which gives identical values at a fraction of the
cost. Encoder positions and the velocity estimate are produced at the internal step and then
decimated to the published rate (default 200 Hz, the two-step paper's rate).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from wrenchd.models.errors import ConfigError
from wrenchd.models.physics.model import PhysicsModel
from wrenchd.models.series import GroundTruth, JointStates, Session
from wrenchd.adapters.sim.sensors import SensorConfig, quantise, velocity_estimate
from wrenchd.adapters.sim.trajectory import FourierTrajectory


class SimulatorConfig(BaseModel):
    """Rates and sensors of the simulated robot."""

    model_config = ConfigDict(extra="forbid")

    internal_rate_hz: float = Field(default=1000.0, gt=0.0, description="internal step rate [Hz]")
    publish_rate_hz: float = Field(default=200.0, gt=0.0, description="published sample rate [Hz]")
    sensors: SensorConfig = Field(default_factory=SensorConfig)

    @model_validator(mode="after")
    def _divides(self):
        ratio = self.internal_rate_hz / self.publish_rate_hz
        if ratio < 1 or abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(
                f"internal_rate_hz ({self.internal_rate_hz}) must be an integer multiple of "
                f"publish_rate_hz ({self.publish_rate_hz})")
        return self

    @property
    def decimation(self) -> int:
        return int(round(self.internal_rate_hz / self.publish_rate_hz))


@dataclass
class Streams:
    """Independent random streams of one simulation run."""

    effort: np.random.Generator
    sensor: np.random.Generator

    @classmethod
    def from_seed(cls, seed: np.random.SeedSequence) -> "Streams":
        a, b = seed.spawn(2)
        return cls(np.random.default_rng(a), np.random.default_rng(b))


def simulate(model: PhysicsModel, trajectory: FourierTrajectory, duration_s: float,
             seed: np.random.SeedSequence, config: SimulatorConfig | None = None,
             force_sensor: bool = False, metadata: dict | None = None) -> Session:
    """Run the simulated PSM for ``duration_s`` seconds.

    Returns a :class:`Session` at the published rate with ground truth: true motion, each
    effect's torque, internal and external torque, the tip wrench, contact flags and, when
    ``force_sensor`` is set, a noisy 6-axis sensor channel.
    """
    cfg = config if config is not None else SimulatorConfig()
    if not duration_s > 0:
        raise ConfigError(f"duration must be > 0 s, got {duration_s}")
    streams = Streams.from_seed(seed)
    dt = 1.0 / cfg.internal_rate_hz
    n_internal = int(round(duration_s * cfg.internal_rate_hz))
    dec = cfg.decimation
    t_int = np.arange(n_internal) * dt
    q_int, dq_int, ddq_int = trajectory.sample(t_int)

    # Sensors at the servo rate, then decimated.
    q_enc = quantise(q_int, cfg.sensors.encoder_resolution)
    dq_est = velocity_estimate(q_enc, dt, cfg.sensors.velocity_cutoff_hz, dq_int[0])
    pub = np.arange(0, n_internal, dec)
    t = t_int[pub]
    motion_pub = model.motion(t, q_int[pub], dq_int[pub], ddq_int[pub])

    effects: dict[str, np.ndarray] = {}
    if any(e.stateful for e in model.effects.values()):
        motion_int = model.motion(t_int, q_int, dq_int, ddq_int)
        effects.update({k: v[pub] for k, v in model.effect_torques(motion_int, stateful=True).items()})
    rigid = model.rigid_body_torque(motion_pub)
    wrench = np.zeros_like(rigid)
    in_contact = np.zeros(len(t), dtype=bool)
    for key, effect in model.effects.items():
        if effect.stateful:
            continue
        if model.is_external(key):                 # the wrench is ground truth too: once
            w, c = effect.wrench(motion_pub)
            effects[key] = effect.torque_from_wrench(motion_pub, w, c)
            wrench += w
            in_contact |= c
        else:
            effects[key] = effect.torque(motion_pub)
    effects = {k: effects[k] for k in model.effects}            # model-file order

    internal = rigid.copy()
    external = np.zeros_like(rigid)
    for key, tau in effects.items():
        if model.is_external(key):
            external += tau
        else:
            internal += tau
    effects = {"rigid_body": rigid, **effects}

    noise_std = np.asarray(cfg.sensors.effort_noise_std)
    effort = internal + external + streams.effort.normal(0.0, 1.0, rigid.shape) * noise_std
    sensor_wrench = None
    if force_sensor:
        s = cfg.sensors
        std = np.array([s.ft_force_noise_std_n] * 3 + [s.ft_torque_noise_std_nm] * 3)
        sensor_wrench = wrench + streams.sensor.normal(0.0, 1.0, wrench.shape) * std

    joint_states = JointStates(t, q_enc[pub], dq_est[pub], effort)
    truth = GroundTruth(
        position=q_int[pub], velocity=dq_int[pub], acceleration=ddq_int[pub],
        internal_torque=internal, external_torque=external, external_wrench=wrench,
        in_contact=in_contact, effects=effects, sensor_wrench=sensor_wrench,
    )
    meta = dict(metadata or {})
    meta.setdefault("simulator", cfg.model_dump(mode="json"))
    meta.setdefault("physics_model", model.to_dict())
    return Session(joint_states, truth, meta)
