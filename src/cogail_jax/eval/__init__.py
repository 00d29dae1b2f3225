"""Evaluation: the device programs (interpolation, replay), the reporting protocol and its figures."""
