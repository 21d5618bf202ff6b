"""Benchmark of the mismatch diagnosis (calib.diagnosis): compute time per diagnosis with a breakdown by phase,
and the wall time of ``calib diagnose FILE``.

Run: .venv/bin/python benchmarks/bench_diagnosis.py [--seeds 5] [--sessions null_a accel_lever_arm] [--no-cli]
     [--cli-only] [--cli-reps 3]

The sessions are those of the concealed-effect proof (:mod:`calib.studies.diagnosis_proof`: the Liu 2021 calibration
session of the study with one hidden effect), diagnosed exactly as the proof does: the seeds of one session share
the geometry and the first seed's library (``library_from``), with the slow noise measured on a long static record of
the same unit (``noise_record``, a simulated 2 h static record). The first seed is a warm-up (it builds the geometry
and the library, and compiles what numba compiles); min / median are over the following seeds.

Phases: the time of ``diagnose_dataset`` is attributed to the *outermost* hooked function running (hooks are
perf_counter wrappers installed on the module attributes the diagnosis calls through; nothing in the package is
changed). What no hook covers (glue, the rank check) is listed as "other", so the phases add up to the total.
"""
from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable

#: phase -> [(module, attribute)]: the calls that belong to the phase (outermost hook wins)
PHASES = {
    "set-up / geometry / library": [
        ("calib.diagnosis.vector", "build_geometry"), ("calib.diagnosis.vector", "reduce_data"),
        ("calib.diagnosis.vector", "covariance_parts"), ("calib.diagnosis.vector", "reduced_inputs"),
        ("calib.diagnosis.vector", "base_design"), ("calib.diagnosis.vector", "build_library"),
        ("calib.diagnosis.vector", "prepare_library"), ("calib.diagnosis.vector", "fit"),
        ("calib.diagnosis.vector", "pulse_counter_channels"), ("calib.diagnosis.run", "setup_norm_problem")],
    "noise estimation (Allan, REML, factors)": [
        ("calib.diagnosis.vector", "fit_noise"), ("calib.diagnosis.vector", "reml_slow"),
        ("calib.diagnosis.vector", "covariance_blocks"), ("calib.diagnosis.vector", "with_measured_slow"),
        ("calib.diagnosis.analysis", "renoise")],
    "base fit": [("calib.diagnosis.analysis", "fit")],
    "candidate tests (stepwise, refine)": [
        ("calib.diagnosis.analysis", "stepwise"), ("calib.diagnosis.analysis", "refine_signatures")],
    "estimates, aliases, absent bounds, identifiability": [
        ("calib.diagnosis.analysis", "param_entries"), ("calib.diagnosis.analysis", "_aliases"),
        ("calib.diagnosis.analysis", "_absent"), ("calib.diagnosis.analysis", "library_geometry"),
        ("calib.diagnosis.analysis", "separating_segments")],
    "open search / rivals / confirmation / adequacy": [
        ("calib.diagnosis.analysis", "confirm_on_measured_noise"), ("calib.diagnosis.analysis", "open_search"),
        ("calib.diagnosis.analysis", "form_alternatives"), ("calib.diagnosis.analysis", "adequacy"),
        ("calib.diagnosis.analysis", "unexplained_entries")],
    "locate / report": [
        ("calib.diagnosis.analysis", "locate"), ("calib.diagnosis.analysis", "block_table"),
        ("calib.diagnosis.analysis", "_untestable"), ("calib.diagnosis.run", "build_report"),
        ("calib.diagnosis.run", "inconclusive_report")],
}


class PhaseTimer:
    """perf_counter hooks on module attributes; the time of a call goes to the phase of the outermost hook."""

    def __init__(self):
        self.acc = {p: 0.0 for p in PHASES}
        self.depth = 0
        self._saved = []

    def install(self):
        import importlib
        for phase, targets in PHASES.items():
            for mod, attr in targets:
                m = importlib.import_module(mod)
                if not hasattr(m, attr):
                    continue
                orig = getattr(m, attr)
                self._saved.append((m, attr, orig))
                setattr(m, attr, self._wrap(orig, phase))

    def uninstall(self):
        for m, attr, orig in reversed(self._saved):
            setattr(m, attr, orig)
        self._saved = []

    def _wrap(self, fn, phase):
        def wrapped(*a, **k):
            if self.depth:
                return fn(*a, **k)
            self.depth += 1
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                self.acc[phase] += time.perf_counter() - t0
                self.depth -= 1
        return wrapped

    def reset(self):
        self.acc = {p: 0.0 for p in PHASES}


def _noise_record(d: Path) -> str:
    from calib.sim.static_session import simulate_static_session
    path = d / "static_2h.nc"
    simulate_static_session({"mode": "counts", "duration_h": 2.0,
                             "site": {"latitude_deg": 30.58, "height_m": 0.0}, "sample_rate_hz": 100.0,
                             "attitude_deg": {"pitch": 0.0, "roll": 0.0, "yaw": 0.0}},
                            20261125, path, d / "static_2h.truth.json")
    return str(path)


def bench_session(name, seeds, noise_record, workdir):
    """Per-diagnosis compute times (s) of ``seeds`` after a warm-up seed, and the phase sums over them."""
    from calib.diagnosis import DEFAULT_SETTINGS, diagnose_dataset
    from calib.studies.diagnosis_proof import FastSession, proof_config

    cfg = proof_config(name)
    spec, drop = cfg.pop("unmodelled", None), cfg.pop("drop_vars", ())
    fsn = FastSession(cfg, workdir, unmodelled=spec, drop_vars=drop)
    st = {**DEFAULT_SETTINGS, "figures": False, "noise_record": noise_record}
    dss = [fsn.dataset(s).load() for s in [seeds[0] - 1] + list(seeds)]   # data made before timing
    t0 = time.perf_counter()
    _, prob0 = diagnose_dataset(dss[0], None, st, path=f"{name} warm-up", library_from=None)
    t_warm = time.perf_counter() - t0
    timer = PhaseTimer()
    timer.install()
    times, verdicts = [], []
    try:
        for sd, ds in zip(seeds, dss[1:]):
            t0 = time.perf_counter()
            rep, _ = diagnose_dataset(ds, None, st, path=f"{name} seed {sd}", library_from=prob0)
            times.append(time.perf_counter() - t0)
            verdicts.append(rep["verdict"])
    finally:
        timer.uninstall()
    return {"name": name, "warm": t_warm, "times": times, "phases": dict(timer.acc), "verdicts": verdicts,
            "template": fsn.path}


def bench_cli(recording, noise_record, out, reps=3):
    """``(rows, load)``: wall and CPU times of ``python -m calib.cli diagnose`` (a new process each: start-up,
    reading and checking the files, the whole diagnosis with its library, and the figures), with and without figures
    and with and without the noise record; the runs of one repetition are interleaved, so that a change of the
    machine's load falls on every row alike. The CPU time (user + system) is the steadier number on a shared
    machine; ``load`` is the 1-minute load average before the runs."""
    (out / "nofig.json").write_text('{"figures": false}')
    variants = [([], "default (figures), no noise record", ""),
                (["--settings", str(out / "nofig.json")], "figures off, no noise record", "--settings nofig.json"),
                (["--noise-record", str(noise_record)], "default (figures), noise record", "--noise-record NR"),
                (["--noise-record", str(noise_record), "--settings", str(out / "nofig.json")],
                 "figures off, noise record", "--noise-record NR --settings nofig.json")]
    base = [PY, "-m", "calib.cli", "diagnose", str(recording), "--out", str(out / "diag"), "--force"]
    load = os.getloadavg()[0]
    for extra, _, _ in variants:   # not timed: byte code and numba's cache written, the files in the page cache
        subprocess.run(base + extra, cwd=ROOT, capture_output=True)
    walls = {label: [] for _, label, _ in variants}
    cpus = {label: [] for _, label, _ in variants}
    for _ in range(reps):
        for extra, label, _ in variants:
            shutil.rmtree(out / "diag", ignore_errors=True)
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            r = subprocess.run(base + extra, cwd=ROOT, capture_output=True, text=True)
            walls[label].append(time.perf_counter() - t0)
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpus[label].append(r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime)
            if r.returncode not in (0, 1, 3):
                raise RuntimeError(r.stderr)
    rows = [(label, " ".join(["calib diagnose FILE --out DIR --force", opts]).strip(), walls[label], cpus[label])
            for _, label, opts in variants]
    # start-up alone: what `calib diagnose` imports before it reads the recording (the parser registers the
    # sub-commands of every command group)
    walls, cpus = [], []
    for _ in range(reps):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([PY, "-c", "import calib.cli, calib.diagnosis"], cwd=ROOT, check=True)
        walls.append(time.perf_counter() - t0)
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpus.append(r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime)
    rows.append(("start-up only", 'python -c "import calib.cli, calib.diagnosis"', walls, cpus))
    return rows, load


def bytecode_state() -> str:
    """Whether calib's modules start from cached byte code: with PYTHONDONTWRITEBYTECODE set (some shells and
    sandboxes) and no cache, every process compiles calib's ~45 modules again (~0.3 s)."""
    import importlib.util

    src = sorted((ROOT / "src" / "calib").rglob("*.py"))
    fresh = 0
    for f in src:
        pyc = Path(importlib.util.cache_from_source(str(f)))
        fresh += pyc.exists() and pyc.stat().st_mtime >= f.stat().st_mtime
    writes = "not written (PYTHONDONTWRITEBYTECODE)" if os.environ.get("PYTHONDONTWRITEBYTECODE") else "written"
    return f"calib byte code: {fresh} of {len(src)} modules cached, new caches {writes}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="timed seeds per session (after the warm-up seed)")
    ap.add_argument("--sessions", nargs="+", default=["null_a", "accel_lever_arm"])
    ap.add_argument("--no-cli", action="store_true", help="skip the calib diagnose wall times")
    ap.add_argument("--cli-reps", type=int, default=3)
    ap.add_argument("--cli-only", action="store_true",
                    help="only the calib diagnose wall times (on the first session's template recording)")
    ap.add_argument("--compile", action="store_true",
                    help="write calib's byte-code caches first (python -m compileall), as any first run does where "
                         "PYTHONDONTWRITEBYTECODE is not set")
    args = ap.parse_args(argv)
    if args.compile:
        subprocess.run([PY, "-m", "compileall", "-q", str(ROOT / "src" / "calib")], check=True)
    if args.cli_only:
        with tempfile.TemporaryDirectory(prefix="bench-diag-") as tmp:
            tmp = Path(tmp)
            nr = _noise_record(tmp)
            cli = bench_cli(_template(args.sessions[0], tmp / args.sessions[0]), nr, tmp, args.cli_reps)
        _print_cli(cli, args.sessions[0])
        return
    seeds = list(range(101, 101 + args.seeds))
    cmdline = "python benchmarks/bench_diagnosis.py " + " ".join(argv if argv is not None else sys.argv[1:])
    with tempfile.TemporaryDirectory(prefix="bench-diag-") as tmp:
        tmp = Path(tmp)
        nr = _noise_record(tmp)
        res = []
        for name in args.sessions:
            wd = tmp / name
            wd.mkdir()
            res.append(bench_session(name, seeds, nr, wd))
        cli = None if args.no_cli else bench_cli(res[0]["template"], nr, tmp, args.cli_reps)
    print(f"## Diagnosis compute time per seed (`{cmdline.strip()}`)\n")
    print("| session | warm-up seed (builds library) [s] | min [s] | median [s] | verdicts |")
    print("|---|---|---|---|---|")
    for r in res:
        print(f"| {r['name']} | {r['warm']:.3f} | {min(r['times']):.3f} | {statistics.median(r['times']):.3f} | "
              f"{', '.join(sorted(set(r['verdicts'])))} |")
    print("\n## Breakdown by phase (mean per timed seed, s)\n")
    print("| phase | " + " | ".join(r["name"] for r in res) + " |")
    print("|---|" + "---|" * len(res))
    for p in PHASES:
        print(f"| {p} | " + " | ".join(f"{r['phases'][p] / len(r['times']):.3f}" for r in res) + " |")
    print("| other (glue, rank check) | " + " | ".join(
        f"{(sum(r['times']) - sum(r['phases'].values())) / len(r['times']):.3f}" for r in res) + " |")
    print("| **total** | " + " | ".join(f"**{sum(r['times']) / len(r['times']):.3f}**" for r in res) + " |")
    if cli:
        _print_cli(cli, res[0]["name"])


def _template(name, workdir) -> Path:
    """The template recording of proof session ``name`` (what :func:`bench_session` diagnoses), alone."""
    from calib.studies.diagnosis_proof import FastSession, proof_config

    cfg = proof_config(name)
    spec, drop = cfg.pop("unmodelled", None), cfg.pop("drop_vars", ())
    Path(workdir).mkdir()
    return FastSession(cfg, workdir, unmodelled=spec, drop_vars=drop).path


def _print_cli(cli, name):
    rows, load = cli
    print(f"\n## `calib diagnose` wall time (fresh process; file: {name} template recording; "
          f"load average {load:.2f} before and {os.getloadavg()[0]:.2f} after the runs on {os.cpu_count()} CPUs; "
          f"{bytecode_state()})\n")
    print("| run | command | wall min [s] | wall median [s] | CPU median [s] |")
    print("|---|---|---|---|---|")
    for label, cmd, walls, cpus in rows:
        print(f"| {label} | `{cmd}` | {min(walls):.2f} | {statistics.median(walls):.2f} | "
              f"{statistics.median(cpus):.2f} |")


if __name__ == "__main__":
    main()
