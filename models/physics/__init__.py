"""PSM physics: kinematics, rigid-body dynamics, effects, model files."""
