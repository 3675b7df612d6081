"""Line-scan stereovision: camera model, calibration, simulator and processor (the paper)."""
