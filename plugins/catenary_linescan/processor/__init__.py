"""Line-scan stereovision processor (the paper, section 3): features, matching, wear."""
