"""calib: reproducible calibration of strapdown inertial navigation systems and gyro-drift estimation."""
__version__ = "0.1.0"
