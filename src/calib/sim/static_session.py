"""Long stationary sessions, written chunk by chunk (memory flat in the duration); deterministic functions of
``(cfg, seed)``:

* mode ``physical`` — He 2019 §IV.A: a stationary unit, increments dtheta [rad] and dv [m/s] (float64), constant
  gyro drift, gyro random walk, accelerometer bias.
* mode ``counts`` — the calibration unit (same :class:`calib.core.triad.TriadModel` pair, noise model, effects and
  quantisation as :mod:`calib.sim.calibration_session`) at rest, for Liu 2021's static navigation check (§4).
"""
from __future__ import annotations

import math
import time as _time
from pathlib import Path

import numpy as np
import xarray as xr

from calib.core import earth
from calib.io import recording
from calib.io.atomic import write_json
from calib.io.netcdf import CF_VERSION, provenance
from calib.sim.counts_engine import (NOISE_BLOCK, SENSOR_NAME, STREAM_PHYSICAL_ACCEL, STREAM_PHYSICAL_GYRO,
                                     BlockNormals, CountsEngine, counts_recording_attrs)
from calib.sim.settings import (STATIC_COUNTS_DEFAULTS, STATIC_PHYSICAL_DEFAULTS, SimConfigError, StaticLayout,
                                attitude, merge, physical_noise, simulated_site, site, static_layout, unit_settings,
                                vector)
from calib.sim.truth import static_counts_truth, static_physical_truth

WHERE = "static_session"


def time_chunking(n: int, target: int) -> int:
    """Samples per file chunk along ``time`` of a long stationary recording: about ``target``, splitting the
    ``n`` samples into equal chunks (the last one short by fewer samples than there are chunks, so the file
    carries almost no padding). Chunks of about 2**20 samples (24 MB of a float64 triad) are read by one large
    request each: cold-cache reading of the 240 h session is about twice as fast as with 2**18."""
    target = max(1, min(int(target), int(n)))
    k = -(-int(n) // target)
    return -(-int(n) // k)


def _attitude_attrs(att: dict) -> dict:
    return {"attitude_pitch_deg": att["pitch"], "attitude_roll_deg": att["roll"], "attitude_yaw_deg": att["yaw"]}


def simulate_static_session(cfg: dict, seed: int, out_path, truth_path=None, prov=None, progress=None,
                            chunk_samples: int = 1 << 20) -> Path:
    """A long stationary recording written chunk by chunk (memory flat in the duration).

    ``cfg['mode']``:

    * ``'physical'`` (default; He 2019 §IV.A) keys :data:`calib.sim.settings.STATIC_PHYSICAL_DEFAULTS`:
      increments ``dtheta = (C_n^b omega_ie^n + drift) dt + noise`` [rad] and ``dv = (C_n^b (0, 0, gamma) + bias)
      dt + noise`` [m/s], float64. Gyro noise ``model: arw`` — angle random walk ``arw_deg_rth`` [deg/sqrt(h)],
      per-sample sigma ``arw/60 sqrt(dt)`` deg; ``model: white`` — white rate noise of sigma ``white_deg_h``
      [deg/h] per sample (sigma ``white dt``). Accel VRW ``accel_vrw_ug_rthz`` [ug/sqrt(Hz)].
    * ``'counts'`` keys :data:`calib.sim.settings.STATIC_COUNTS_DEFAULTS`: the calibration unit's int32 pulse
      counts (same sensor, noise model, effects and quantisation as
      :func:`calib.sim.calibration_session.simulate_calibration_session`) plus the temperature channel.

    Attitude ``attitude_deg: {pitch, roll, yaw}`` (ENU convention of :mod:`calib.core.rotations`; zero = body
    axes along E, N, U). ``progress(done_samples, total_samples)`` is called after each chunk.
    ``chunk_samples`` changes only memory use and file chunking (chunks of about that many samples along
    ``time``, see :func:`time_chunking`), never the samples. ``truth_path``: the JSON sidecar
    (:mod:`calib.sim.truth`).
    """
    mode = (cfg or {}).get("mode", "physical")
    if mode not in ("physical", "counts"):
        raise SimConfigError(f"{WHERE}.mode: {mode!r}; use 'physical' or 'counts'")
    c = merge(cfg, STATIC_PHYSICAL_DEFAULTS if mode == "physical" else STATIC_COUNTS_DEFAULTS, WHERE)
    layout = static_layout(c)
    chunk_samples = time_chunking(layout.n_samples, chunk_samples)  # written by whole file chunks
    t_wall = _time.perf_counter()
    if prov is None:
        prov = provenance("simulate_static_session", cfg, seed)
    write = _static_physical if mode == "physical" else _static_counts
    truth = write(c, seed, out_path, prov, progress, chunk_samples, layout)
    truth["generation_time_s"] = _time.perf_counter() - t_wall
    if truth_path is not None:
        write_json(truth, truth_path)
    return Path(out_path)


def static_physical_means(cfg: dict) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free per-sample increments (dtheta [rad], dv [m/s]) of a physical-mode static session."""
    c = merge(cfg, STATIC_PHYSICAL_DEFAULTS, WHERE)
    lat, h = site(c, WHERE)
    cbn, _ = attitude(c, WHERE)
    dt = 1.0 / float(c["sample_rate_hz"])
    drift = vector(c["gyro_drift_deg_h"], f"{WHERE}.gyro_drift_deg_h") * earth.DEG_PER_H
    bias = vector(c["accel_bias_m_s2"], f"{WHERE}.accel_bias_m_s2")
    w_ib = cbn.T @ earth.earth_rate_enu(math.radians(lat)) + drift
    f_b = cbn.T @ np.array([0.0, 0.0, float(earth.normal_gravity(math.radians(lat), h))]) + bias
    return w_ib * dt, f_b * dt


def _static_physical(c, seed, out_path, prov, progress, chunk, layout: StaticLayout) -> dict:
    n, fs = layout.n_samples, layout.sample_rate_hz
    pn = physical_noise(c, 1.0 / fs, WHERE)
    dth0, dv0 = static_physical_means(c)
    normals_g = BlockNormals(seed, STREAM_PHYSICAL_GYRO, 3)
    normals_a = BlockNormals(seed, STREAM_PHYSICAL_ACCEL, 3) if pn.sigma_accel_m_s > 0 else None
    attrs = {"session": "stationary navigation (He 2019 IV.A)", "body_frame": "right-front-up",
             "navigation_frame": "ENU", **_attitude_attrs(layout.attitude_deg)}
    with recording.LongRecordingWriter(out_path, n, fs, latitude_deg=layout.latitude_deg, height_m=layout.height_m,
                                       accel_units="m s-1", gyro_units="rad", accel_kind="increment",
                                       gyro_kind="increment", dtype="f8", source="synthetic",
                                       sensor="He 2019 simulated stationary INS", extra_attrs=attrs,
                                       chunk_samples=chunk) as w:
        for i0 in range(0, n, chunk):
            i1 = min(n, i0 + chunk)
            dth = dth0 + pn.sigma_gyro_rad * normals_g.get(i0, i1)
            dv = (dv0 + pn.sigma_accel_m_s * normals_a.get(i0, i1) if normals_a is not None
                  else np.broadcast_to(dv0, (i1 - i0, 3)))
            w.append(dv, dth)
            if progress is not None:
                progress(i1, n)
    return static_physical_truth(c, seed, layout, pn, dth0, dv0)


def _static_counts_unit(c, seed, layout: StaticLayout):
    """The calibration unit at rest of a counts-mode static session: ``(engine, unit settings, simulated site)``."""
    unit = unit_settings(c, WHERE)
    world = simulated_site(layout.latitude_deg, layout.height_m, unit.effects)
    w_ib = layout.cbn.T @ earth.earth_rate_enu(math.radians(world.latitude_deg))
    f_b = layout.cbn.T @ np.array([0.0, 0.0, world.gravity_m_s2])
    zero = np.zeros(3)

    def inputs(t):
        k = len(t)
        z = np.broadcast_to(zero, (k, 3))
        return np.broadcast_to(f_b, (k, 3)), np.broadcast_to(w_ib, (k, 3)), z, z

    eng = CountsEngine(unit.accel, unit.gyro, unit.noise, unit.effects, world, layout.sample_rate_hz, seed, inputs,
                       unit.temperature, n_nodes=1, constant_inputs=True)
    return eng, unit, world


def _static_counts_attrs(c, eff, quant, att) -> dict:
    return counts_recording_attrs(c["conceal"], eff, quant, {"session": "static", **_attitude_attrs(att)})


def _static_counts(c, seed, out_path, prov, progress, chunk, layout: StaticLayout) -> dict:
    eng, unit, world = _static_counts_unit(c, seed, layout)
    n, quant = layout.n_samples, unit.noise["quantize"]
    attrs = _static_counts_attrs(c, unit.effects, quant, layout.attitude_deg)
    with recording.LongRecordingWriter(out_path, n, layout.sample_rate_hz, latitude_deg=layout.latitude_deg,
                                       height_m=layout.height_m, accel_units="count", gyro_units="count",
                                       accel_kind="increment", gyro_kind="increment", dtype="i4" if quant else "f8",
                                       source="synthetic", sensor=SENSOR_NAME, extra_attrs=attrs,
                                       chunk_samples=chunk, temperature=True) as w:
        for i0 in range(0, n, chunk):
            ch = eng.next(min(chunk, n - i0))
            w.append(ch.accel, ch.gyro, ch.temperature)
            if progress is not None:
                progress(i0 + len(ch.accel), n)
    return static_counts_truth(c, seed, layout, unit, world)


def static_counts_dataset(cfg: dict, seed: int, chunk_samples: int = NOISE_BLOCK, path: str | None = None):
    """The counts-mode static session of ``(cfg, seed)`` in memory: the ``xarray.Dataset`` that
    ``recording.load`` returns for the file :func:`simulate_static_session` writes (same samples, dtypes, variable
    and global attributes; ``temperature`` float32 as stored), without the file and its provenance attributes.
    ``path``: the ``_path`` attribute a loaded file carries (default: none). For the many short records of a
    study (the whole record is held in memory; generated by chunks of ``chunk_samples``, which keeps the
    temporaries small and changes no sample)."""
    c = merge(cfg, STATIC_COUNTS_DEFAULTS, WHERE)
    if c["mode"] != "counts":
        raise SimConfigError(f"{WHERE}.mode: {c['mode']!r}; the in-memory static record is counts only")
    layout = static_layout(c)
    lat, h, fs, n = layout.latitude_deg, layout.height_m, layout.sample_rate_hz, layout.n_samples
    eng, unit, _ = _static_counts_unit(c, seed, layout)
    # the samples do not depend on the chunk size (calib.sim.counts_engine), only the memory does
    acc, gyr, temp = eng.run(n, max(1, int(chunk_samples)), temperature_dtype=np.float32)
    attrs = {"Conventions": f"{CF_VERSION} {recording.CONVENTIONS}", "latitude_deg": lat, "height_m": h,
             "sample_rate_hz": fs, "t0_s": 0.0, "source": "synthetic", "sensor": SENSOR_NAME}
    attrs.update(_static_counts_attrs(c, unit.effects, unit.noise["quantize"], layout.attitude_deg))
    attrs = {k: np.float64(v) if isinstance(v, float) else v for k, v in attrs.items()}  # as netCDF4 reads them
    if path is not None:
        attrs["_path"] = str(path)
    data = {"accel": (("time", "axis"), acc, {"sample_kind": "increment", "units": "count",
                                              "long_name": "accelerometer triad output"}),
            "gyro": (("time", "axis"), gyr, {"sample_kind": "increment", "units": "count",
                                             "long_name": "gyroscope triad output"}),
            "temperature": (("time",), temp, {"units": "degC", "long_name": "unit temperature"})}
    coords = {"axis": list(recording.AXES), "time": 0.0 + np.arange(n) / fs}
    return xr.Dataset(data, coords=coords, attrs=attrs)
