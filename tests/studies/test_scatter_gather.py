"""The workflow runs the long studies as one job per part and a gathering job: the concealed-effect proof per
session and per detection-power scan, the real-recording proof per recording, the z-score study per block of
seeds. Gathering the parts written by those jobs gives the same files, byte for byte, as the one-process run of
the same configuration (the products a study had before it was split)."""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest
import xarray as xr
import yaml

from calib.io.netcdf import provenance
from calib.studies import calibration as cs
from calib.studies import diagnosis_stage as diagnosis_study
from calib.studies import proof_sessions
from calib.studies import real_proof as rp

ROOT = Path(__file__).resolve().parents[2]
REAL = Path(os.environ.get("CALIB_DATA") or ROOT.parent / "shared" / "data")   # where import_real reads
needs_real = pytest.mark.skipif(not REAL.is_dir(), reason=f"shared real-data directory {REAL} is missing")

#: a short session (one revolution, 20 s dwells) of the default unit at 30.58 deg
SHORT = {"dwell_s": 20.0, "revolutions": 1}
SITE = {"latitude_deg": 30.58, "height_m": 0.0}


def _files(folder: Path) -> dict:
    """Every file under ``folder`` but the wall times and the netCDF (compared by content), by relative path."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != "timings.json" and p.suffix != ".nc"}


def test_proof_gathered_from_session_and_scan_jobs_equals_one_run(tmp_path):
    """A null session and a single effect with its power scan (two seeds each), each session a job of its own (the
    scan from the session's result; the second session reads its seeds' noise from the store the first wrote),
    then gathered in another order: every product the same as the one-process stage. Two seeds of a 20-s dwell
    cannot hold the proof's claims (the gate's pooled coverage alone needs 50 intervals: tests/diagnosis/
    test_proof_gate.py), so the gate reports here without failing the stage: this test is about the products."""
    names = ["null_a", "time_offset"]
    assert proof_sessions.session_names([]) == list(proof_sessions.PROOF_SESSIONS)
    assert proof_sessions.session_names(names) == names
    prov = provenance("diagnosis_proof", {"n_seeds": 2}, seed=7)
    one = tmp_path / "one"
    diagnosis_study.proof_stage(one, n_seeds=2, first_seed=7, sessions=names, power_seeds=2, workers=1, base=SHORT,
                                site=SITE, prov=prov, metrics_path=one / "proof.metrics.json", log=lambda *a: None,
                                enforce=False)

    parts, gathered = tmp_path / "parts", tmp_path / "gathered"
    store = tmp_path / "noise"
    store.mkdir()
    for nm in names:
        diagnosis_study.proof_session_stage(nm, parts / nm, 2, 7, base=SHORT, site=SITE, power_seeds=2,
                                            noise_store=store, log=lambda *a: None)
    assert (parts / "time_offset" / "power.json").is_file() and not (parts / "null_a" / "power.json").exists()
    # the two sessions (one unit) share their seeds' noise through the store: one file per seed -- 2 proof seeds,
    # 2 power seeds and seed 0, with which the end-to-end file of a session with a physical effect is rewritten
    assert len(list(store.glob("*.npy"))) == 5 and not list(store.glob("*.part"))
    diagnosis_study.proof_gather_stage(gathered, [parts / nm for nm in reversed(names)], 2, 7, sessions=names,
                                       power_seeds=2, prov=prov, metrics_path=gathered / "proof.metrics.json",
                                       log=lambda *a: None, enforce=False)
    a, b = _files(one), _files(gathered)
    assert sorted(a) == sorted(b)
    assert {"proof.json", "proof.csv", "proof.md", "power.csv", "power.png", "proof_rows.json",
            "figures/residuals_time_offset.png", "end_to_end/null_a/report.json"} <= set(a)
    assert [k for k in a if a[k] != b[k]] == []
    with xr.open_dataset(one / "proof.nc") as x, xr.open_dataset(gathered / "proof.nc") as y:
        xr.testing.assert_identical(x.load(), y.load())
        assert "power_scale" in y   # the scan is in the gathered netCDF
    # a session missing from the parts is refused, naming it
    with pytest.raises(ValueError, match="null_a"):
        diagnosis_study.proof_gather_stage(tmp_path / "short", [parts / "time_offset"], 2, 7, sessions=names,
                                           log=lambda *a: None)


@pytest.fixture(scope="module")
def ccfg():
    c = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())["calibration"]
    return {**c, "NP": 30, "EG": 200, "noise_record": "static_check", "z_noise_record": "per_seed"}


def test_z_scores_gathered_from_seed_blocks_equal_one_run(tmp_path, ccfg):
    """Three seeds as blocks [0, 2) and [2, 3), written and read back in either order: the same table, metrics
    (full float repr) and figure as one run over the three seeds."""
    session = {"sample_rate_hz": 100.0, "dwell_s": 10.0, "revolutions": 1}
    check = {"duration_h": 0.2, "attitude_deg": {"pitch": 0.0, "roll": 0.0, "yaw": 0.0}}
    one = tmp_path / "one"
    cs.run_z_seeds(session, SITE, ccfg, 3, 4242, one / "z.csv", one / "z.png", one / "z.json", one / "work",
                   log=lambda *a: None, check=check)
    paths = []
    for first, stop in ((2, 3), (0, 2)):
        block = cs.z_seed_block(session, SITE, ccfg, 4242, first, stop, tmp_path / "work", check=check,
                                progress=False)
        paths.append(cs.write_z_block(block, first, tmp_path / "parts" / f"{first}_{stop}.json"))
    two = tmp_path / "two"
    cs.z_products(cs.read_z_blocks(paths), ccfg, 3, two / "z.csv", two / "z.png", two / "z.json", log=lambda *a: None)
    assert _files(one) == _files(two)
    assert json.loads((two / "z.json").read_text())["n_seeds"] == 3
    # a block left out is refused (the table would silently hold fewer seeds)
    with pytest.raises(ValueError, match="seeds 0 .. 1"):
        cs.read_z_blocks(paths[:1])
    with pytest.raises(ValueError, match="3 seeds configured, 2"):
        cs.z_products(cs.read_z_blocks(paths[1:]), ccfg, 3, two / "z.csv", two / "z.png", two / "z.json")


@needs_real
def test_real_proof_gathered_from_recording_jobs_equals_one_run(tmp_path):
    """A usable proof base (mikoff) and one with too few poses (smac), each as a job of its own, gathered in either
    order: the same four files and metrics as the one-process stage."""
    cfg = dict(reps=2, n_inject=2, n_out=1, seed=5)
    names = ["mikoff_imu0", "smac_adis16405"]
    one = tmp_path / "one"
    rp.real_proof_stage(one, ROOT / "config" / "import", recordings=names, workers=1, axes=("x",), enforce=False,
                        metrics_path=one / "m.json", log=lambda *a: None, **cfg)
    parts = []
    for nm in reversed(names):
        r = rp.real_proof_recording(ROOT / "config" / "import" / f"{nm}.yaml", axes=("x",), **cfg)
        parts.append(rp.write_part(r, tmp_path / "parts" / f"{nm}.json"))
    two = tmp_path / "two"
    rp.real_proof_gather(two, ROOT / "config" / "import", parts, recordings=names, enforce=False,
                         metrics_path=two / "m.json", log=lambda *a: None, **cfg)
    assert _files(one) == _files(two)
    with pytest.raises(ValueError, match="no_such_recording"):
        rp.real_proof_gather(tmp_path / "x", ROOT / "config" / "import", parts, recordings=["no_such_recording"])


def _critical_path_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("critical_path", ROOT / "benchmarks" / "critical_path.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod   # its dataclass looks its module up
    spec.loader.exec_module(mod)
    return mod


def test_critical_path_is_the_longest_chain_by_job_time(tmp_path, capsys):
    """A hand-made study: sim (2 s) feeds two scattered parts (10 s, 30 s) and a gather (1 s); calib (25 s) runs
    beside them; 'all' needs both. The longest chain is sim -> part b -> gather = 33 s (not the longest job alone,
    not the sum of all 68 s); a job without a benchmark file counts 0 s and is named."""
    cp = _critical_path_module()
    bench = tmp_path / "r" / "benchmarks"
    bench.mkdir(parents=True)
    for name, s in (("sim", 2.0), ("part.a", 10.0), ("part.b", 30.0), ("gather", 1.0), ("calib", 25.0)):
        (bench / f"{name}.tsv").write_text(f"s\th:m:s\tmax_rss\n{s}\t0:00:{int(s):02d}\t10.0\n")

    def job(rule, jobid, inp, out, bm, wc=""):
        return (f"\n[Sat Nov 28 07:00:00 2026]\nrule {rule}:\n    input: {', '.join(inp)}\n    output: {', '.join(out)}\n"
                f"    jobid: {jobid}\n" + (f"    benchmark: {bm}\n" if bm else "") + "    reason: Forced execution\n"
                + (f"    wildcards: {wc}\n" if wc else "") + "    resources: tmpdir=/tmp\n")

    text = "".join([
        job("sim", 1, [], ["r/data/s.nc"], "r/benchmarks/sim.tsv"),
        job("part", 2, ["r/data/s.nc"], ["r/parts/a"], "r/benchmarks/part.a.tsv", "p=a"),
        job("part", 3, ["r/data/s.nc"], ["r/parts/b"], "r/benchmarks/part.b.tsv", "p=b"),
        job("gather", 4, ["r/parts/a", "r/parts/b"], ["r/g.json"], "r/benchmarks/gather.tsv"),
        job("calib", 5, [], ["r/c.csv"], "r/benchmarks/calib.tsv"),
        job("fig", 6, ["r/c.csv"], ["r/c.png"], ""),
        "\nlocalrule all:\n    input: r/g.json, r/c.png\n    jobid: 0\n    reason: Forced execution\n",
    ])
    jobs = cp.parse_dry_run(text)
    assert [j.rule for j in jobs] == ["sim", "part", "part", "gather", "calib", "fig", "all"]
    for j in jobs:
        j.seconds = cp.job_seconds(tmp_path / j.benchmark) if j.benchmark else None
    total, chain = cp.critical_path(jobs)
    assert total == 33.0 and [j.label for j in chain] == ["sim", "part[p=b]", "gather", "all"]
    saved = tmp_path / "dry.txt"
    saved.write_text(text)
    assert cp.main(["--dry-run-output", str(saved), "--workdir", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "critical path: 33.0 s of job time over 4 jobs (7 jobs in the study, 68.0 s of job time in all)" in out
    assert "without a benchmark file (counted 0 s): rules fig" in out
    # nothing run yet: no benchmark file, a short message and exit 2
    assert cp.main(["--dry-run-output", str(saved), "--workdir", str(tmp_path / "empty")]) == 2
    assert "run the study first" in capsys.readouterr().err
