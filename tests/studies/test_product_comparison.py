"""``tools/hash_products.py --numeric``: two results folders compared product by product, saying by how much they
differ -- checked on folders made here with known perturbations (the truth of each verdict is the perturbation)."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import netCDF4
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("hash_products", ROOT / "tools" / "hash_products.py")
hp = importlib.util.module_from_spec(spec)
spec.loader.exec_module(hp)


def _nc(path: Path, x: np.ndarray, label: str = "a", commit: str = "abc"):
    with netCDF4.Dataset(path, "w") as nc:
        nc.git_commit = commit
        nc.label = label
        nc.createDimension("n", x.size)
        v = nc.createVariable("x", "f8", ("n",))
        v[:] = x
        k = nc.createVariable("k", "i4", ("n",))
        k[:] = np.arange(x.size)
        name = nc.createVariable("name", str, ("n",))   # a string variable (read as an object array)
        for i in range(x.size):
            name[i] = f"window {i}"


def _folder(root: Path, *, nc_scale=1.0, nc_label="a", json_p=0.25, md_value="0.1234", md_word="pass",
            png_pixel=0, png_level=1, commit="abc") -> Path:
    root.mkdir()
    x = np.linspace(1.0, 2.0, 50)
    _nc(root / "v.nc", x * nc_scale, nc_label, commit)
    (root / "r.json").write_text(json.dumps({"p": json_p, "verdict": "explained", "git_commit": commit,
                                             "wall_time_s": 3.0 if commit == "abc" else 4.0, "n": 3}))
    (root / "t.md").write_text(f"| term | value | verdict |\n|---|---|---|\n| N | {md_value} | {md_word} |\n")
    from PIL import Image

    img = np.zeros((4, 4, 3), np.uint8)
    img[0, 0, 0] = png_pixel
    Image.fromarray(img).save(root / "f.png", compress_level=png_level, pnginfo=None)
    return root


def _verdicts(a, b, rtol=1e-9, capsys=None):
    code = hp.numeric(a, b, rtol)
    out = capsys.readouterr().out.splitlines()[1:]
    return code, {line.split("\t")[0]: line.split("\t")[1:] for line in out}


def test_identical_folders_and_volatile_fields(tmp_path, capsys):
    a = _folder(tmp_path / "a")
    b = _folder(tmp_path / "b", commit="def")   # another commit and wall time: not a difference
    code, v = _verdicts(a, b, capsys=capsys)
    assert code == 0 and v == {}


def test_rounding_level_moves_are_within_and_sized(tmp_path, capsys):
    a = _folder(tmp_path / "a")
    # and the PNG written with another compression: other bytes, the same pixels
    b = _folder(tmp_path / "b", nc_scale=1.0 + 3e-13, json_p=0.25 * (1 + 2e-14), md_value="0.1235", png_level=0)
    assert (a / "f.png").read_bytes() != (b / "f.png").read_bytes()
    code, v = _verdicts(a, b, capsys=capsys)
    assert code == 0, v
    assert v["v.nc"][0] == "within" and float(v["v.nc"][1].split()[-1]) == pytest.approx(3e-13, rel=0.05)
    assert v["r.json"][0] == "within" and float(v["r.json"][1].split()[-1]) == pytest.approx(2e-14, rel=0.05)
    assert v["t.md"] == ["within", "1 in the last printed digit"]
    assert v["f.png"] == ["within", "same pixels"]


def test_real_differences_are_named(tmp_path, capsys):
    a = _folder(tmp_path / "a")
    cases = {"v.nc": dict(nc_scale=1.0 + 1e-6), "r.json": dict(json_p=0.3), "t.md": dict(md_word="fail"),
             "f.png": dict(png_pixel=7)}
    for name, kw in cases.items():
        b = _folder(tmp_path / f"b_{name}", **kw)
        code, v = _verdicts(a, b, capsys=capsys)
        assert code == 1 and set(v) == {name} and v[name][0] == "DIFFERS", (name, v)
    b = _folder(tmp_path / "b_md2", md_value="0.1237")        # 3 units in the last digit: beyond print rounding
    code, v = _verdicts(a, b, capsys=capsys)
    assert code == 1 and v["t.md"] == ["DIFFERS", "3 in the last printed digit"]
    b = _folder(tmp_path / "b_attr", nc_label="b")              # a netCDF attribute is not a number
    code, v = _verdicts(a, b, capsys=capsys)
    assert code == 1 and v["v.nc"][0] == "DIFFERS" and "label" in v["v.nc"][1]
    (b / "t.md").unlink()
    code, v = _verdicts(a, b, capsys=capsys)
    assert code == 1 and v["t.md"] == ["missing after", ""]
