"""docs/real_data.md lists every real file the tests read, with its size and SHA-256: checked
against the real data folder when it is there."""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "real_data.md"
ROW = re.compile(r"^\| `([^`]+)` \| (\d+) \| `([0-9a-f]{64})` \|")


def listed() -> dict[str, tuple[int, str]]:
    out = {}
    for line in DOC.read_text(encoding="utf-8").splitlines():
        m = ROW.match(line)
        if m:
            out[m.group(1)] = (int(m.group(2)), m.group(3))
    return out


def test_the_list_names_the_files_and_the_skip_message_points_to_it():
    files = listed()
    assert len(files) == 12 and {n.rsplit(".", 1)[1] for n in files} == {"pcd", "mcap"}
    assert "docs/real_data.md" in (Path(__file__).parent / "conftest.py").read_text()


def test_the_real_data_folder_matches_the_list(real_data):
    files = listed()
    present = {p.name for p in real_data.iterdir() if p.suffix in (".pcd", ".mcap")}
    assert present == set(files), f"not listed: {sorted(present - set(files))}, missing: {sorted(set(files) - present)}"
    for name, (size, sha) in files.items():
        data = (real_data / name).read_bytes()
        assert (len(data), hashlib.sha256(data).hexdigest()) == (size, sha), name
    for lic in ("LICENSE-pcl-data.txt", "LICENSE-pcl.txt", "LICENSE-pointcloudset.txt"):
        assert (real_data / lic).is_file() and lic in DOC.read_text()


def test_no_test_imports_a_conftest_by_name():
    """``import conftest`` means whichever conftest.py pytest loaded last (tests/zcut has its own): CI's run of
    stop 56 failed on it. The real data's folder is named in tests/real_data_path.py; fixtures come as fixtures."""
    tests = Path(__file__).parent
    pattern = re.compile(r"^\s*(import conftest\b|from conftest import)", re.MULTILINE)
    found = [str(p.relative_to(tests)) for p in sorted(tests.rglob("*.py")) if pattern.search(p.read_text("utf-8"))]
    assert found == []
