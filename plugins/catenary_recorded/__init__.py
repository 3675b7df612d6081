"""Recorded run files (HDF5) as an acquisition source."""
