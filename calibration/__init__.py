"""Calibration data: the demo rig, its captures and their ground truth (shipped as package data)."""
