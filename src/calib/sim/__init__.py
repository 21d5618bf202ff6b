"""Synthetic sessions: the turntable path and its exact kinematics (``trajectory``, Liu 2021 §2.2 and §3.3), the
library of extra physics (``effects``) and the simulator (``simulator``) of calibration sessions and He 2019
stationary navigation data."""
