"""Workflows: pose-estimator outputs to editable, effector-driven scenes on custom characters."""
