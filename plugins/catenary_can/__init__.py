"""CAN bus acquisition: displacement sensors and wheel encoder (python-can, cantools)."""
