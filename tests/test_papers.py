"""benchmarks.papers: one section in quick form writes its files with finite numbers."""
import csv
import math

import pytest

from benchmarks import papers


def test_section_003_quick(tmp_path):
    files = papers.reproduce(tmp_path, sections=["003"], seeds=[0, 1], progress=False)
    names = {f.name for f in files}
    assert {"report.md", "seed003.md", "seed003_table.csv", "seed003_runs.csv", "seed003_spectra.png"} <= names
    assert all(f.exists() and f.stat().st_size > 0 for f in files)
    with open(tmp_path / "seed003_table.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["case"] for r in rows] == ["static", "dynamic", "vibration"]
    for r in rows:
        for k in ("ekf_var", "ukf_var", "iir-ekf_var", "red_vs_ekf_pct"):
            assert math.isfinite(float(r[k]))
        assert float(r["ekf_var"]) > 0
    # vibration must show in the roll noise, far above the still case
    assert float(rows[2]["ekf_var"]) > 10 * float(rows[0]["ekf_var"])
    with open(tmp_path / "seed003_runs.csv") as fh:
        assert len(list(csv.DictReader(fh))) == 3 * 2 * 3          # cases x seeds x estimators
    md = (tmp_path / "report.md").read_text()
    assert "33.52 %" in md and "reproduced" in md
    assert (tmp_path / "seed003_spectra.png").read_bytes()[:4] == b"\x89PNG"


def test_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="sections must be some of 000, 001, 003, 004"):
        papers.reproduce(tmp_path, sections=["002"], progress=False)
    with pytest.raises(ValueError, match="seeds"):
        papers.run_section("000", tmp_path, seeds=[])
