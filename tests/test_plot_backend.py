"""The library never chooses the user's matplotlib backend (issue 17, hygiene): its figures
are drawn on Figure objects of their own canvas, not through pyplot."""
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("matplotlib")
ROOT = Path(__file__).resolve().parents[1]


def test_no_package_module_uses_pyplot_or_sets_the_backend():
    bad = []
    for pkg in ("fusion", "envs", "controllers"):
        for f in sorted((ROOT / pkg).rglob("*.py")):
            text = f.read_text()
            if re.search(r"matplotlib\.use\(|import matplotlib\.pyplot|from matplotlib import pyplot", text):
                bad.append(str(f.relative_to(ROOT)))
    assert not bad, f"these set the backend or go through pyplot: {bad}"


def test_plots_keep_the_callers_backend(tmp_path):
    code = f"""
import matplotlib
matplotlib.use("svg")
import matplotlib.pyplot as plt
import numpy as np
from benchmarks.compare import plot_errors
from controllers.compare import _plot_paths
plot_errors({{"p": {{"a": np.ones(50)}}}}, {str(tmp_path / 'e.png')!r}, "t", fs=10.0)
row = dict(path=np.zeros((3, 2)), start=np.zeros(2), waypoints=np.ones((1, 2)), waypoint_radius=0.5,
           estimator="ekf", controller="pid", task="waypoints", scenario="flat", episode_seed=0)
_plot_paths([row], {str(tmp_path / 'p.png')!r})
print(matplotlib.get_backend())
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().lower() == "svg"
    assert (tmp_path / "e.png").stat().st_size > 1000 and (tmp_path / "p.png").stat().st_size > 1000


def test_benchmark_figures_are_written_atomically(tmp_path, monkeypatch):
    """benchmarks.compare.save_figure (accuracy.png, loso's chart, the estimator comparison's
    figures): a save that fails halfway keeps the previous file whole, no temporary left."""
    import matplotlib.figure
    from benchmarks import compare
    path = tmp_path / "fig.png"
    fig = compare.new_figure()
    fig.subplots().plot([0, 1], [0, 1])
    compare.save_figure(fig, path)
    before = path.read_bytes()
    assert before.startswith(b"\x89PNG")

    def broken(self, fname, *a, **k):
        fname.write(b"partial") if hasattr(fname, "write") else Path(fname).write_bytes(b"partial")
        raise OSError("disk full")
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", broken)
    with pytest.raises(OSError, match="disk full"):
        compare.save_figure(fig, path)
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["fig.png"]
