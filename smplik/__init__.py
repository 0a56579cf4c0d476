"""smplik: morphology-aware learned inverse kinematics on the SMPL body model."""

__version__ = "0.1.0"
