#!/usr/bin/env python3
"""Set up calib in its own virtual environment and run the study or the tests.

    python3 run.py study   # create .venv, install, run the full default study (config/config.yaml)
    python3 run.py test    # create/reuse .venv, install, run pytest (one worker per core) with the .test workflow
                           # beside it, the import-layer contract, snakemake --lint, the CF check of the .test products
                           # and the documentation built with warnings as errors (mkdocs build --strict)
    python3 run.py setup [--slurm]   # create/reuse .venv and install; --slurm adds the SLURM executor plugin
                                     # (the slurm extra; docs/scale-out.md)

Needs only Python >= 3.11 and pip. Extra arguments after the verb go to snakemake (study) or pytest (test).
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = Path(os.environ.get("CALIB_VENV", ROOT / ".venv"))
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
PY = BIN / "python"


def sh(*cmd, **kw):
    print("+", " ".join(map(str, cmd)), flush=True)
    r = subprocess.run([str(c) for c in cmd], cwd=kw.pop("cwd", ROOT), **kw)
    if r.returncode != 0:
        sys.exit(r.returncode)


class Beside:
    """A command run in the background while the tests run (the .test workflow: neither uses both cores all the
    time -- the tests wait on subprocesses, the workflow on its one-after-the-other rules -- so side by side they
    take about 40 s less than one after the other on two cores). Its output goes to ``log`` and is printed whole
    by :meth:`finish`, which fails as :func:`sh` does; leaving the block any other way (a failed test, Ctrl-C)
    stops it with its process group."""

    def __init__(self, what, log, *cmd, env=None):
        self.what, self.log, self.cmd, self.env, self.proc = what, Path(log), [str(c) for c in cmd], env, None

    def __enter__(self):
        self.log.parent.mkdir(parents=True, exist_ok=True)
        print(f"+ {self.what}, beside the tests (output in {self.log.relative_to(ROOT)})", flush=True)
        with open(self.log, "w") as fh:
            self.proc = subprocess.Popen(self.cmd, cwd=ROOT, env=self.env, stdout=fh, stderr=subprocess.STDOUT,
                                         start_new_session=os.name != "nt")
        return self

    def finish(self):
        if self.proc.poll() is None:
            print(f"waiting for {self.what} ...", flush=True)
        rc = self.proc.wait()
        print(f"---- {self.what} ({self.log.relative_to(ROOT)}):", flush=True)
        print(self.log.read_text(errors="replace"), end="", flush=True)
        print(f"---- {self.what}: exit {rc}", flush=True)
        if rc != 0:
            sys.exit(rc)

    def __exit__(self, *exc):
        if self.proc.poll() is None:   # the tests failed or were interrupted: the workflow stops too
            import signal

            try:
                os.killpg(self.proc.pid, signal.SIGTERM) if os.name != "nt" else self.proc.terminate()
                self.proc.wait(timeout=60)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
            print(f"{self.what} stopped (log: {self.log.relative_to(ROOT)})", flush=True)
        return False


def setup(extras=("workflow", "test")):
    """The virtual environment with calib and the ``extras`` a verb needs (the study: the workflow; the tests: the
    test tools too). What is installed is kept in ``.calib-installed`` (pyproject.toml, then the extras): a changed
    pyproject.toml installs again, a further extra installs beside those already there."""
    if sys.version_info < (3, 11):
        sys.exit(f"calib needs Python >= 3.11, this is {sys.version.split()[0]}")
    if not PY.exists():
        print(f"creating virtual environment {VENV}", flush=True)
        venv.EnvBuilder(with_pip=True).create(VENV)
    stamp = VENV / ".calib-installed"
    spec = (ROOT / "pyproject.toml").read_bytes()
    have = set()
    if stamp.exists():
        text = stamp.read_bytes()
        head, _, tail = text.rpartition(b"\n# extras: ")
        if head == spec:
            have = set(tail.decode().split(",")) - {""}
    need = set(extras)
    if not need <= have:
        if not have:
            sh(PY, "-m", "pip", "install", "--quiet", "--upgrade", "pip")
        want = sorted(need | have)
        sh(PY, "-m", "pip", "install", "--quiet", "-e", f"{ROOT}[{','.join(want)}]")
        stamp.write_bytes(spec + b"\n# extras: " + ",".join(want).encode())
    env = dict(os.environ)
    env["PATH"] = f"{BIN}{os.pathsep}{env.get('PATH', '')}"
    return env


def pytest_workers(rest):
    """pytest on every core this process may use (pytest-xdist): whole files per worker (``--dist loadfile``), so
    that a module's fixtures are computed once; the files are started longest first (tests/conftest.py).
    ``CALIB_TEST_WORKERS`` sets the number; ``python3 run.py test -n 0`` (a later ``-n`` wins) runs serially."""
    if any("no:xdist" in a for a in rest):
        return []
    n = os.environ.get("CALIB_TEST_WORKERS") or str(len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                                                    else os.cpu_count() or 1)
    return ["-n", n, "--dist", "loadfile", "--no-loadscope-reorder"]


def lazy_bytecode():
    """Byte code for the study and the tests: pip would compile all ~11 000 modules of a fresh environment one after
    the other (two thirds of the install's time); a run imports a third of them. So pip does not compile, and every
    process writes the cache of a module when it first imports it (PYTHONDONTWRITEBYTECODE, if set, is lifted), in
    parallel, the calib sources included."""
    os.environ.setdefault("PIP_COMPILE", "0")
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)


def main(argv):
    verb = argv[0] if argv else "help"
    rest = argv[1:]
    if verb == "study":
        lazy_bytecode()
        env = setup(("workflow",))   # the study needs no test tools
        sh(BIN / "snakemake", "--profile", "workflow/profiles/default", *rest, env=env)
    elif verb == "test":
        lazy_bytecode()
        env = setup()
        # beside the tests: the small workflow, its lint, the CF check of its products, the docs (_chain below)
        chain = Beside("the .test workflow, its lint, the CF check of its products and the docs build",
                       ROOT / ".test" / "results" / "logs" / "test_chain.log", sys.executable, __file__, "_chain",
                       env=env)
        with chain:
            sh(PY, "-m", "pytest", "-q", *pytest_workers(rest), *rest, env=env)
            sh(BIN / "lint-imports", env=env)  # the layer contract of pyproject.toml [tool.importlinter]
            chain.finish()
    elif verb == "_chain":   # what `test` runs beside pytest (its output goes to the chain's log)
        env = setup()
        env_strict = dict(env, CALIB_FIGURE_CHECK="strict")  # a figure with an empty panel, etc. fails the rule
        # the small workflow on its own profile (.test/config.yaml, a thread a rule, the proof first: in a fresh clone
        # it compiles numba's diagnosis kernels, which the diagnosis rules after it then load from the cache)
        sh(BIN / "snakemake", "--profile", "workflow/profiles/test", env=env_strict)
        sh(BIN / "snakemake", "--lint", "--configfile", ".test/config.yaml", env=env)
        # CF-1.11 oracle on every kind of netCDF the workflow writes (one optimizer run file stands for all)
        res = ROOT / ".test" / "results"
        ncs = sorted(p for p in res.rglob("*.nc") if p.parent.name != "runs") + [res / "calibration" / "runs" /
                                                                                "accel_ide.nc"]
        sh(PY, "tools/cf_check.py", *map(str, ncs), env=env)
        # the documentation (mkdocs.yml) with warnings as errors, API reference included; the site is thrown away
        with tempfile.TemporaryDirectory(prefix="calib-site-") as site:
            sh(BIN / "mkdocs", "build", "--strict", "--quiet", "--site-dir", site, env=env)
    elif verb == "setup":
        setup(("workflow", "test") + (("slurm",) if "--slurm" in rest else ()))
    else:
        print(__doc__)
        sys.exit(0 if verb in ("help", "-h", "--help") else 2)


if __name__ == "__main__":
    main(sys.argv[1:])
