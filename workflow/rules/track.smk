# Tracking: the store is initialised once before any job starts (parallel jobs opening a fresh SQLite
# store can corrupt it); after a successful run every stage's metrics, the config, wall times and the
# figures and tables are logged as one MLflow run. Set MLFLOW_TRACKING_URI to use a tracking server;
# set CALIB_TRACKING=0 to switch tracking off (e.g. for dry runs).
import os


def _tracking_on():
    return os.environ.get("CALIB_TRACKING", "1") != "0" and not workflow.dryrun if hasattr(workflow, "dryrun") else os.environ.get("CALIB_TRACKING", "1") != "0"


onstart:
    if _tracking_on():
        from calib.studies import tracking

        print("tracking store:", tracking.init_store(R))


onsuccess:
    if _tracking_on():
        from calib.studies import tracking

        try:
            rid = tracking.collect(R, config, run_name=config.get("run_name", ""))
            print(f"tracked as MLflow run {rid} in {tracking.tracking_uri(R)}")
        except tracking.TrackingError as exc:
            print(f"TRACKING FAILED (scientific outputs are intact): {exc}")
            raise SystemExit(1)
