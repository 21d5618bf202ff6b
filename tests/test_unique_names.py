"""pytest imports test files by their base name (no packages under tests/): two files of one name in different
folders make the second fail to collect ("import file mismatch"). Every test file name is unique."""
from collections import Counter
from pathlib import Path


def test_test_file_names_are_unique():
    names = Counter(p.name for p in Path(__file__).resolve().parent.rglob("test_*.py"))
    assert not [n for n, k in names.items() if k > 1]
