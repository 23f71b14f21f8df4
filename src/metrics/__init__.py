"""Metrics: rotation conversions, the Euler-angle error of the papers, forward kinematics, MPJPE."""
