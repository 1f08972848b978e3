"""C2D2 learned branch: calibration-free depth, ego-motion and intrinsics; coverage networks."""
