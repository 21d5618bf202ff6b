"""Synthetic sessions: the turntable path and its exact kinematics (``trajectory``, Liu 2021 §2.2 and §3.3), the
library of extra physics (``effects``), and the simulator of calibration sessions and He 2019 stationary
navigation data, one module per concern:

* ``settings`` — the configuration keys, their defaults and checks (:class:`calib.sim.settings.SimConfigError`
  names the key and the fix);
* ``counts_engine`` — the unit's output: noise-free increments of the sensor model, the noise streams and the
  pulse counter;
* ``calibration_session`` — the Liu 2021 calibration session (24 positions and the ± rotation windows) as a
  ``calib-recording-1`` file of pulse counts;
* ``static_session`` — long stationary sessions: He 2019 §IV.A physical increments, or the calibration unit's
  counts at rest (Liu 2021 §4);
* ``truth`` — the JSON truth sidecar of each session.

Beside the simulator: the same effects by a second, physical path the diagnosis does not use (``physical``),
physics outside the diagnosis library (``unmodelled``) and Fisher bounds of the effects (``fisher``).
"""
