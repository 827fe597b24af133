"""Identification of a physics model from free-motion joint data (pure: arrays in, arrays out).

- :mod:`~wrenchd.models.identification.differentiation`: accelerations from a smoothed derivative of
  the measured velocity.
- :mod:`~wrenchd.models.identification.base_parameters`: which inertial columns are identifiable.
- :mod:`~wrenchd.models.identification.free_motion`: least-squares fit of base parameters, per-joint
  Coulomb and viscous friction and offsets, written as a model file.
"""
