# Tracking: after a successful run every stage's metrics, the config, wall times and the figures and tables are
# logged as one MLflow run. The store is created once per run by one process before anything logs to it (parallel
# writers opening a fresh SQLite store can corrupt it): no job touches it, so that process runs beside the first
# jobs (creating a new store -- MLflow's schema migrations -- takes ~4 s, which the whole run used to wait for),
# and onsuccess / onerror wait for it to end (an unreachable tracking server is then said at the end: exit 1, the
# scientific outputs intact). Set MLFLOW_TRACKING_URI to use a tracking server; set
# CALIB_TRACKING=0 to switch tracking off (e.g. for dry runs).
import os
import subprocess
import sys

_STORE = []   # the process creating the tracking store (onstart), awaited before the run is logged

_CREATE_STORE = """
import sys
from calib.studies import tracking
try:
    print(tracking.init_store(sys.argv[1]))
except tracking.TrackingError as exc:
    print(exc, file=sys.stderr)
    sys.exit(1)
"""


def _tracking_on():
    return os.environ.get("CALIB_TRACKING", "1") != "0" and not workflow.dryrun if hasattr(workflow, "dryrun") else os.environ.get("CALIB_TRACKING", "1") != "0"


def _store_ready():
    """Wait for the store's creation (never left half-made); '' when it is ready, else why not."""
    if not _STORE:
        return ""
    p = _STORE.pop()
    out, err = p.communicate()
    if p.returncode != 0:
        lines = err.strip().splitlines()
        return lines[-1] if lines else f"creating the store ended with exit code {p.returncode}"
    print("tracking store:", out.strip())
    return ""


onstart:
    if _tracking_on():
        _STORE.append(subprocess.Popen([sys.executable, "-c", _CREATE_STORE, R], stdout=subprocess.PIPE,
                                       stderr=subprocess.PIPE, text=True))


onsuccess:
    if _tracking_on():
        why = _store_ready()
        if why:
            print(f"TRACKING FAILED (scientific outputs are intact): {why}")
            raise SystemExit(1)
        from calib.studies import tracking

        try:
            rid = tracking.collect(R, config, run_name=config.get("run_name", ""))
            print(f"tracked as MLflow run {rid} in {tracking.tracking_uri(R)}")
        except tracking.TrackingError as exc:
            print(f"TRACKING FAILED (scientific outputs are intact): {exc}")
            raise SystemExit(1)


onerror:
    _store_ready()
