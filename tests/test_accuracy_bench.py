"""benchmarks/accuracy.py end to end on a tiny subset (skipped without the peer libraries)."""
import csv
import math

import pytest

for _peer in ("vqf", "imufusion", "ahrs"):
    pytest.importorskip(_peer)

from benchmarks import accuracy, compare, peers  # noqa: E402  (after the peers' importorskip)


def test_ideal_check_refuses_a_peer_fed_in_the_wrong_frame():
    good = peers.ahrs_method("Madgwick")
    bad = peers.ahrs_method("Madgwick")
    bad.name, bad.nav = "madgwick-as-ENU", "ENU"      # its output is NWU: heading off by 90 deg
    rows, failed = accuracy.ideal_check([good, bad], 10.0, print)
    assert good.name not in failed
    assert "madgwick-as-ENU" in failed and "heading" in failed["madgwick-as-ENU"]


def test_quick_subset_writes_tables_and_figure(tmp_path):
    res = accuracy.main(["--quick", "--max-trials", "1", "--trial-seconds", "5", "--duration", "5",
                         "--scenarios", "slow", "--no-progress", "--out", str(tmp_path)])
    # every peer's feeding (units, frame) passed the noise-free check
    assert not [n for n, _ in res["failed"].items() if not n.startswith("fusion.")], res["failed"]
    for f in ("accuracy.md", "accuracy.png", "accuracy_overall.csv", "accuracy_runs.csv",
              "accuracy_ideal_check.csv", "accuracy_synthetic_9-axis.md"):
        assert (tmp_path / f).stat().st_size > 0, f
    # the ratio chart: every method over VQF on every recorded cell
    recorded = {r["set"] for r in res["rows"]} - {accuracy.SYNTHETIC, accuracy.SEED}
    assert (tmp_path / "accuracy_ratio.png").is_file() == bool(recorded)
    # every error scored, but total and heading where the reference heading is not north
    only = compare.INCLINATION_ONLY
    assert res["rows"] and all(math.isfinite(r[k]) for r in res["rows"] for k in accuracy.ERRORS
                               if k == "inclination" or (r["set"], r["mode"]) not in only)
    assert all(math.isnan(r["total"]) and math.isnan(r["heading"]) for r in res["rows"]
               if (r["set"], r["mode"]) in only)

    # the "ours / best peer" column is the best of ours over the best peer of each group, by
    # total (by inclination in an inclination-only cell)
    groups = {(r["set"], r["mode"]) for r in res["agg"]}
    with open(tmp_path / "accuracy_overall.csv") as f:
        overall = {(r["set"], r["mode"]): r for r in csv.DictReader(f)}
    assert set(overall) == groups
    for key in groups:
        k = "inclination" if key in only else "total"
        sub = [r for r in res["agg"] if (r["set"], r["mode"]) == key]
        ours = min(r[k] for r in sub if r["group"] == "ours")
        peer = min(r[k] for r in sub if r["group"] == "peer")
        assert float(overall[key]["ours / best peer"]) == pytest.approx(ours / peer)
        assert {r["method"] for r in sub} >= {"fusion.ekf", "vqf.VQF", "ahrs.EKF"}
    if any(s == "repoimu_tstick" for s, _ in groups):     # recorded data present
        assert ("repoimu_tstick", "9-axis") in groups and ("ese650", "6-axis") in groups
        assert ("ese650", "9-axis") not in groups          # no magnetometer there


def test_loso_worst_trial_is_the_largest_ratio_to_vqf():
    """benchmarks/loso.py's worst-trial line: per error, the largest ours / VQF ratio over
    every cell's trials; a cell judged by inclination alone has no total."""
    from benchmarks import loso

    def cell(set_, mode, names, ours, vqf):
        c = loso.Cell(set_, mode, names, [None] * len(names))
        c.vqf = [dict(total=t, inclination=i) for t, i in vqf]
        return c, [dict(total=t, inclination=i) for t, i in ours]

    a, ra = cell("tstick", "6-axis", ["t1", "t2"], [(2.0, 1.0), (3.0, 0.5)], [(1.0, 1.0), (2.0, 0.1)])
    b, rb = cell("diodem", "9-axis", ["d1"], [(90.0, 0.6)], [(1.0, 0.3)])
    worst = loso.worst_trials({a.key: ra, b.key: rb}, [a, b])
    assert worst["total"] == (2.0, "tstick 6-axis", "t1")          # diodem 9-axis's 90x is not judged
    assert worst["inclination"] == (5.0, "tstick 6-axis", "t2")


def test_loso_ratio_interval_is_paired():
    """The ratio's interval resamples the same trials for ours and VQF: trials of very
    different difficulty, ours 1.1x VQF on each, give 1.1 with no spread (an unpaired
    interval would span the difficulty); a mixed cell's interval holds its ratio."""
    from benchmarks import loso
    c = loso.Cell("s", "6-axis", ["a", "b", "c", "d", "e", "f"], [None] * 6)
    c.vqf = [dict(total=v) for v in (0.5, 1.0, 4.0, 9.0, 2.0, 0.7)]
    lo, hi = loso.ratio_ci([dict(total=1.1 * r["total"]) for r in c.vqf], c)
    assert lo == pytest.approx(1.1) and hi == pytest.approx(1.1)
    ours = [dict(total=v) for v in (0.4, 1.3, 3.9, 9.5, 2.2, 0.6)]
    lo, hi = loso.ratio_ci(ours, c)
    assert lo < loso.ratio(ours, c) < hi
