"""controllers.curves: the training curves read from the runs' evaluation logs."""
import json

import numpy as np
import pytest

from controllers import curves


def _run(tmp_path, name, seed, timesteps, returns, task="track", estimator="truth"):
    stem = tmp_path / name
    (tmp_path / f"{name}.run").mkdir()
    np.savez(tmp_path / f"{name}.run" / "evaluations.npz", timesteps=np.array(timesteps),
             results=np.array(returns, dtype=float), ep_lengths=np.ones((len(timesteps), 2), dtype=int))
    (tmp_path / f"{name}.json").write_text(json.dumps({"task": task, "estimator": estimator, "seed": seed,
                                                       "init_from": "pid (behaviour cloning, 10 steps)"}))
    return stem


def test_seed_spread_over_common_timesteps(tmp_path):
    a = curves.load_run(_run(tmp_path, "a", 0, [0, 10, 20], [[1, 3], [2, 2], [5, 7]]))
    b = curves.load_run(_run(tmp_path, "b", 1, [10, 20, 30], [[4, 4], [0, 2], [9, 9]]))
    assert a["mean_return"].tolist() == [2, 2, 6] and a["seed"] == 0
    t, mean, lo, hi = curves.seed_spread([a, b])
    assert t.tolist() == [10, 20]                      # only where both evaluated
    assert mean.tolist() == [3, 3.5] and lo.tolist() == [2, 1] and hi.tolist() == [4, 6]


def test_plot_writes_one_panel_per_task_and_estimator(tmp_path):
    pytest.importorskip("matplotlib")
    runs = [curves.load_run(_run(tmp_path, f"r{i}", i, [0, 10], [[i, i], [i + 1, i + 1]], task=task, estimator=est))
            for i, (task, est) in enumerate([("track", "truth"), ("track", "truth"), ("waypoints", "ekf")])]
    drawn = curves.plot_training_curves(runs, tmp_path / "c.png")
    assert sorted(drawn) == [("track", "truth"), ("waypoints", "ekf")]
    assert (tmp_path / "c.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    curves.plot_training_curves(runs, tmp_path / "c.pdf")          # the format its suffix names
    assert (tmp_path / "c.pdf").read_bytes()[:5] == b"%PDF-"
    with pytest.raises(ValueError, match="no runs"):
        curves.plot_training_curves([], tmp_path / "d.png")


def test_bad_run_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing"):
        curves.load_run(tmp_path / "missing")
    stem = _run(tmp_path, "bad", 0, [0], [[1.0]])
    (tmp_path / "bad.run" / "evaluations.npz").write_bytes(b"not an npz")
    with pytest.raises(ValueError, match="not an evaluation log"):
        curves.load_run(stem)
