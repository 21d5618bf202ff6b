"""Experiment tracking: every workflow run becomes one MLflow run.

Each stage of the workflow writes a small ``*.metrics.json`` beside its products (scientific files never
hold timings). After a successful workflow run, :func:`collect` gathers all of them with the flattened
config as parameters, the wall times from Snakemake's ``benchmark:`` files, and the figures and tables as
artifacts, into the tracking store.

Store: ``MLFLOW_TRACKING_URI`` when set (a tracking server), else a local SQLite file
(``results/mlflow.db``), initialised once by :func:`init_store` before any job starts (a fresh SQLite store
opened by parallel jobs can corrupt).
"""
from __future__ import annotations

import json
import logging
import os
from pathlib import Path

from calib.io.netcdf import config_hash, git_commit


class TrackingError(RuntimeError):
    """The tracking store cannot be reached; scientific outputs are left as they are."""


def tracking_uri(results_dir) -> str:
    uri = os.environ.get("MLFLOW_TRACKING_URI")
    if uri:
        return uri
    return "sqlite:///" + str((Path(results_dir) / "mlflow.db").resolve())


def _quiet():
    for name in ("mlflow", "alembic", "sqlalchemy"):
        logging.getLogger(name).setLevel(logging.ERROR)
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")


def init_store(results_dir, experiment="calib") -> str:
    """Create (or open) the store and the experiment once, before parallel jobs start. Returns the URI."""
    _quiet()
    import mlflow

    Path(results_dir).mkdir(parents=True, exist_ok=True)
    uri = tracking_uri(results_dir)
    mlflow.set_tracking_uri(uri)
    try:
        client = mlflow.MlflowClient(uri)
        if client.get_experiment_by_name(experiment) is None:
            client.create_experiment(experiment, artifact_location=_artifact_root(results_dir, uri))
    except Exception as exc:  # noqa: BLE001 - any store failure is reported the same way
        raise TrackingError(f"tracking store {uri!r} unreachable: {exc.__class__.__name__}: {exc} -- "
                            "fix: unset MLFLOW_TRACKING_URI or point it at a running server") from exc
    return uri


def _artifact_root(results_dir, uri):
    if uri.startswith("sqlite:"):
        return (Path(results_dir) / "mlartifacts").resolve().as_uri()
    return None


def flatten(d, prefix=""):
    """Flatten nested dicts/lists into ``a.b.c -> value`` strings (MLflow parameters are flat strings)."""
    out = {}
    if isinstance(d, dict):
        for k, v in d.items():
            out.update(flatten(v, f"{prefix}{k}."))
    elif isinstance(d, (list, tuple)) and any(isinstance(v, (dict, list)) for v in d):
        for i, v in enumerate(d):
            out.update(flatten(v, f"{prefix}{i}."))
    else:
        out[prefix[:-1]] = json.dumps(d) if isinstance(d, (list, tuple)) else str(d)
    return out


def gather_metrics(results_dir) -> dict:
    """All numeric metrics of ``*.metrics.json`` files under ``results_dir``, keyed ``stage.name``."""
    metrics = {}
    for p in sorted(Path(results_dir).rglob("*.metrics.json")):
        stage = p.name[: -len(".metrics.json")]
        rel = p.parent.relative_to(results_dir).as_posix().replace("/", ".")
        key0 = f"{rel}.{stage}" if rel != "." else stage
        for k, v in flatten(json.loads(p.read_text())).items():
            try:
                metrics[f"{key0}.{k}"] = float(v)
            except (TypeError, ValueError):
                continue
    return metrics


def gather_benchmarks(results_dir) -> dict:
    """Wall times [s] from Snakemake ``benchmark:`` TSV files under ``results_dir/benchmarks``."""
    out = {}
    for p in sorted((Path(results_dir) / "benchmarks").rglob("*.tsv")):
        lines = p.read_text().splitlines()
        if len(lines) >= 2:
            head, row = lines[0].split("\t"), lines[1].split("\t")
            if "s" in head:
                out["wall_s." + p.stem] = float(row[head.index("s")])
    return out


def collect(results_dir, config: dict, run_name: str = "", experiment="calib", artifacts=True) -> str:
    """Log one run with params (flattened config), metrics, wall times and artifacts. Returns the run id."""
    _quiet()
    import mlflow

    uri = init_store(results_dir, experiment)
    try:
        client = mlflow.MlflowClient(uri)
        exp = client.get_experiment_by_name(experiment)

        run = client.create_run(exp.experiment_id, run_name=run_name or f"study-{config_hash(config)}",
                                tags={"config_hash": config_hash(config), "git_commit": git_commit()})
        rid = run.info.run_id
        from mlflow.entities import Metric, Param

        params = [Param(k[:250], v[:6000]) for k, v in sorted(flatten(config).items())]
        metrics = {**gather_metrics(results_dir), **gather_benchmarks(results_dir)}
        mets = [Metric(k[:250], v, 0, 0) for k, v in sorted(metrics.items())]
        for i in range(0, len(params), 100):
            client.log_batch(rid, params=params[i:i + 100])
        for i in range(0, len(mets), 500):
            client.log_batch(rid, metrics=mets[i:i + 500])
        if artifacts:
            for p in sorted(Path(results_dir).rglob("*")):
                if p.suffix in (".png", ".csv", ".md", ".json") and "mlartifacts" not in p.parts:
                    sub = p.parent.relative_to(results_dir).as_posix()
                    client.log_artifact(rid, str(p), artifact_path=None if sub == "." else sub)
        client.set_terminated(rid)
        return rid
    except TrackingError:
        raise
    except Exception as exc:  # noqa: BLE001
        raise TrackingError(f"logging to tracking store {uri!r} failed: {exc.__class__.__name__}: {exc}") from exc
