"""``pip install calib`` gives the library and the ``calib`` command without the workflow's dependencies
(snakemake, mlflow: the ``workflow`` extra). Checked in a process where importing them fails, as on such an install."""
import subprocess
import sys
import textwrap

BLOCK = textwrap.dedent("""
    import importlib.abc, sys

    class Absent(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in ("snakemake", "mlflow", "alembic", "sqlalchemy"):
                raise ModuleNotFoundError(f"No module named {name!r}", name=name)
            return None

    sys.meta_path.insert(0, Absent())
""")


def _run(code, *args):
    return subprocess.run([sys.executable, "-c", BLOCK + textwrap.dedent(code), *args], capture_output=True,
                          text=True, timeout=300)


def test_every_module_imports_without_the_workflow_extra():
    r = _run("""
        import importlib, pkgutil, calib
        bad = []
        for m in pkgutil.walk_packages(calib.__path__, "calib."):
            if m.name.endswith(".__main__"):   # runs the command on import
                continue
            try:
                importlib.import_module(m.name)
            except ModuleNotFoundError as exc:
                bad.append(f"{m.name}: {exc}")
        print("\\n".join(bad))
        sys.exit(1 if bad else 0)
    """)
    assert r.returncode == 0, r.stdout + r.stderr


def test_blocker_works():
    """The stand-in for a missing package is effective (else the test above could not fail)."""
    r = _run("import snakemake")
    assert r.returncode != 0 and "No module named 'snakemake'" in r.stderr


def test_command_line_config_without_snakemake(tmp_path):
    """A study config read by the command line gets its schema defaults without snakemake."""
    r = _run("""
        from calib.cli.shared import study_config
        cfg = study_config(None)
        print(sorted(cfg))
    """)
    assert r.returncode == 0, r.stderr
