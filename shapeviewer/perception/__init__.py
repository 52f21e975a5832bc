"""Perception: captures from depth sensors and files, their segments on the support plane."""
