"""Gyro-drift estimation of He 2019: PSOBE on the pure-inertial navigation error J (``psobe``, eq. 18), its
swarm (``pso``, eqs. 16-19), the baselines (``psobe``: least squares, Kalman filter) and the Cramér–Rao bound of
the problem from the generative model (``bound``)."""
