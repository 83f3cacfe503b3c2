"""benchmarks.papers (the measurements) and benchmarks.papers_report (the report written from
them): one section in quick form writes its files with finite numbers."""
import csv
import math

import numpy as np
import pytest

from benchmarks import papers, papers_report


def test_section_003_quick(tmp_path):
    files = papers_report.reproduce(tmp_path, sections=["003"], seeds=[0, 1], progress=False)
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


def test_the_report_states_the_measured_numbers(tmp_path):
    """The report's sentences with numbers come from the measurement they are given: a
    section whose numbers are changed reports the changed numbers and verdicts."""
    sec = papers.measure("003", seeds=[0, 1])
    assert sec.per_seed["alias_share_pct"].shape == (2,)
    for p in sec.paired:
        p["diffs"] = np.array([1.0, 1.1])                          # as if the IIR-EKF were clearly better
    sec.per_seed["alias_share_pct"] = np.array([12.0, 12.0])
    md = "\n".join(papers_report.write_section(sec, tmp_path)[0])
    assert "12 ± 0 % per seed" in md
    assert md.count("- static: reproduced") == 1 and "not reproduced" not in md


@pytest.mark.parametrize("diffs, word", [
    ([1.0, 1.2, 0.9], "reproduced ("),
    ([-1.0, -1.2, -0.9], "the opposite"),
    ([1.0, -1.0, 0.1], "no difference beyond the seed spread"),
])
def test_verdict(diffs, word):
    assert word in papers_report.verdict(np.array(diffs), "claim")


def test_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="sections must be some of 000, 001, 003, 004"):
        papers_report.reproduce(tmp_path, sections=["002"], progress=False)
    with pytest.raises(ValueError, match="seeds"):
        papers.measure("000", seeds=[])
    with pytest.raises(ValueError, match="unknown section"):
        papers.measure("002", seeds=[0])
