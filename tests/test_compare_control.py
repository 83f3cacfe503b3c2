"""The control comparison grid: planning and bad input, the same results on every backend
(a two-node Ray cluster included), the cell cache and --resume, the outputs."""
import csv
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pybullet")

from controllers import compare

SHORT = {"episode_s": 4.5}   # the steady-state window starts 3 s after a command


def _jobs(estimators=("truth", "gyro"), task="track", episodes=2):
    jobs = compare.plan([task], ["flat"], list(estimators), ["pid"], episodes=episodes, seed=5, log=lambda *a: None)
    for j in jobs:   # short episodes keep the test fast
        j["env_kwargs"].update(SHORT)
    return jobs


def test_plan_skips_missing_policies_and_names_bad_input(tmp_path):
    msgs = []
    jobs = compare.plan(["waypoints"], ["flat"], ["ekf"], ["pid", "ppo", "ppo-truth"], 1, 0,
                        policy_dir=tmp_path, log=msgs.append)
    assert [j["controller"] for j in jobs] == ["pid"]
    assert len(msgs) == 2 and all("no policy" in m for m in msgs)
    for args, what in (((["track"], ["moon"], ["ekf"], ["pid"]), "scenario"),
                       ((["track"], ["flat"], ["ekf"], ["lqr"]), "controller"),
                       ((["track"], ["flat"], ["kalman"], ["pid"]), "estimator"),
                       ((["swim"], ["flat"], ["ekf"], ["pid"]), "task")):
        with pytest.raises(ValueError, match=f"unknown {what}.*accepted: ") as e:
            compare.plan(*args, 1, 0)
        assert "flat" in str(e.value) or "pid" in str(e.value) or "ekf" in str(e.value) or "track" in str(e.value)
    # a name twice ran its cells twice over and repeated their rows in episodes.csv
    with pytest.raises(ValueError, match="estimator.*'ekf' given more than once"):
        compare.plan(["track"], ["flat"], ["truth", "ekf", "ekf"], ["pid"], 1, 0)


def test_cli_bad_input_before_any_work(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(compare, "run_grid", lambda *a, **k: pytest.fail("work started"))
    assert compare.main(["--estimators", "truth,kalman"]) == 2
    err = capsys.readouterr().err
    assert "kalman" in err and "accepted:" in err and "ekf" in err
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert compare.main(["--out", str(blocker / "sub"), "--estimators", "truth"]) == 2
    assert "cannot be written" in capsys.readouterr().err


def test_local_pool_equals_serial_and_summary():
    jobs = _jobs()
    serial = compare.run_grid(jobs, workers=1, progress=False)
    pooled = compare.run_grid(jobs, workers=2, progress=False)
    assert len(serial) == 4
    for a, b in zip(serial, pooled):
        assert a == b
    s = compare.summarise(serial)
    truth = next(r for r in s if r["estimator"] == "truth")
    gyro = next(r for r in s if r["estimator"] == "gyro")
    assert truth["delta_heading_ss"] == 0.0 and (truth["delta_heading_ss_lo"], truth["delta_heading_ss_hi"]) == (0, 0)
    assert math.isfinite(gyro["delta_heading_ss"])
    assert gyro["attitude_error"] > truth["attitude_error"]
    for r in s:          # two episodes: no bootstrap interval (MIN_BOOT)
        for m in compare.SHOWN["track"]:
            assert math.isnan(r[m + "_lo"]) and math.isnan(r[m + "_iqm_hi"])
            if r["estimator"] != "truth":
                assert math.isnan(r["delta_" + m + "_lo"]) and not r["separated"]


def test_cache_resume_and_code_version(tmp_path, monkeypatch):
    jobs = _jobs(episodes=1)
    first = compare.run_grid(jobs, workers=1, progress=False, cache_dir=tmp_path, log=lambda *a: None)
    assert len(list(tmp_path.glob("*.json"))) == 2 and not list(tmp_path.glob("*.tmp"))

    def no_work(job):
        raise AssertionError("a cached cell was run again")
    monkeypatch.setattr(compare, "run_job", no_work)
    msgs = []
    assert compare.run_grid(jobs, workers=1, progress=False, cache_dir=tmp_path, resume=True, log=msgs.append) == first
    assert "2 of 2 cells cached" in msgs[0]
    # other code: nothing reused
    monkeypatch.setattr(compare, "code_version", lambda: "another-version")
    with pytest.raises(AssertionError, match="run again"):
        compare.run_grid(jobs, workers=1, progress=False, cache_dir=tmp_path, resume=True, log=lambda *a: None)
    # a corrupt cache file is not trusted either
    monkeypatch.undo()
    victim = sorted(tmp_path.glob("*.json"))[0]
    victim.write_text("{not json")
    again = compare.run_grid(jobs, workers=1, progress=False, cache_dir=tmp_path, resume=True, log=lambda *a: None)
    assert again == first
    # nor one whose rows are not the cell's (they were taken: a cell without rows, or with a
    # metric missing, which summarise then failed on without naming the file)
    import json
    d = json.loads(victim.read_text())
    for edit in (lambda r: r.clear(), lambda r: r[0].pop("heading_ss"), lambda r: r[0].update(heading_ss="x"),
                 lambda r: r[0].update(episode_seed=99), lambda r: r[0].update(estimator="ekf")):
        rows = json.loads(json.dumps(d["rows"]))
        edit(rows)
        victim.write_text(json.dumps(dict(d, rows=rows)))
        msgs = []
        assert compare.run_grid(jobs, workers=1, progress=False, cache_dir=tmp_path, resume=True,
                                log=msgs.append) == first
        assert any(victim.name in m and "running it again" in m for m in msgs), msgs


def test_ray_two_node_cluster_equals_local(tmp_path, monkeypatch):
    """Two nodes of one CPU each on this machine, two cells of PID and one of PPO; the cells
    the Ray run cached are resumed without running them again."""
    ray = pytest.importorskip("ray")
    from ray.cluster_utils import Cluster
    jobs = _jobs()
    ppo = compare.plan(["track"], ["flat"], ["gyro"], ["ppo"], episodes=1, seed=5, log=lambda *a: None)
    assert len(ppo) == 1         # the shipped policy travels in the working_dir
    ppo[0]["env_kwargs"].update(SHORT)
    jobs += ppo
    local = compare.run_grid(jobs, workers=1, progress=False)
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        with compare.ray_session(address=cluster.address):
            assert len(ray.nodes()) == 2
            via_ray = compare.run_grid(jobs, backend="ray", progress=False, cache_dir=tmp_path, log=lambda *a: None)

            @ray.remote
            def where():
                import controllers
                return controllers.__file__
            # the workers import the package the runtime_env uploaded, not the driver's files
            assert not ray.get(where.remote()).startswith(str(compare.PACKAGE_ROOT))
        assert not ray.is_initialized()
    finally:
        cluster.shutdown()
    assert via_ray == local

    def no_work(job):
        raise AssertionError("a cached cell was run again")
    monkeypatch.setattr(compare, "run_job", no_work)
    assert compare.run_grid(jobs, progress=False, cache_dir=tmp_path, resume=True, log=lambda *a: None) == local


def test_outputs(tmp_path):
    jobs = _jobs()
    rows = compare.run_grid(jobs, workers=1, progress=False)
    path_rows = compare.run_grid([dict(jobs[0], record_path=True, episodes=1)], workers=1, progress=False)
    out = compare.write_outputs(rows, compare.summarise(rows), tmp_path, path_rows=path_rows, log=lambda *a: None)
    for f in ("summary.md", "summary.csv", "episodes.csv", "headline.png", "paths.png"):
        assert (out / f).stat().st_size > 100
    with open(out / "summary.csv") as f:
        header = next(csv.reader(f))
    for col in ("heading_ss", "heading_ss_lo", "heading_ss_hi", "delta_heading_ss", "delta_heading_ss_lo",
                "delta_heading_ss_hi", "heading_ss_iqm"):
        assert col in header
    assert "(reference)" in (out / "summary.md").read_text()
    # without truth: no figure, and the reason written and said
    msgs = []
    no_truth = [r for r in rows if r["estimator"] != "truth"]
    out2 = compare.write_outputs(no_truth, compare.summarise(no_truth), tmp_path / "nt", log=msgs.append)
    assert not (out2 / "headline.png").exists()
    assert "no `truth` estimator" in (out2 / "summary.md").read_text() and any("no `truth`" in m for m in msgs)


def test_summary_success_intervals_in_range():
    rows = []
    for est, outcomes in (("truth", [1, 1, 1, 1]), ("gyro", [0, 1, 0, 0])):
        for i, s in enumerate(outcomes):
            rows.append(dict(task="waypoints", scenario="flat", estimator=est, controller="pid", episode_seed=i,
                             success=float(s), time_to_goal=20.0 + i if s else float("nan"), cross_track=0.2,
                             attitude_error=1.0, tilt_error=0.5, heading_est_error=1.0))
    s = {r["estimator"]: r for r in compare.summarise(rows)}
    g = s["gyro"]
    assert g["success"] == 0.25 and 0.0 <= g["success_lo"] < 0.25 < g["success_hi"] <= 1.0
    assert g["delta_success"] == -0.75 and -1.0 <= g["delta_success_lo"] < -0.75 < g["delta_success_hi"] <= 1.0
    assert g["delta_time_to_goal"] == pytest.approx(21.0 - 21.0)       # the one seed both reached
    k = compare.min_detectable_success(30)
    assert k is not None
    from controllers.evaluation import newcombe_paired
    assert newcombe_paired(np.r_[np.zeros(k), np.ones(30 - k)], np.ones(30))[2] < 0
    assert newcombe_paired(np.r_[np.zeros(k - 1), np.ones(31 - k)], np.ones(30))[2] >= 0


def test_headline_table_is_the_readmes(tmp_path):
    """One row per estimator ranked by the first column's harm, truth's value and the others'
    paired differences per task x controller x floor, written to headline.md too."""
    rows = []
    for task, metric, base in (("track", "heading_ss", 3.0), ("waypoints", "success", 1.0)):
        for sc in ("flat", "disturbed"):
            for ctrl in ("pid", "ppo", "ppo-truth"):
                for est, harm in (("truth", 0.0), ("gyro", 2.0), ("ekf", 0.5)):
                    for i in range(8):
                        v = base + harm + 0.1 * i if task == "track" else float(not (est == "gyro" and i < 4))
                        r = dict.fromkeys(compare.SHOWN[task], 1.0)
                        r.update(task=task, scenario=sc, estimator=est, controller=ctrl, episode_seed=i, **{metric: v})
                        rows.append(r)
    summary = compare.summarise(rows)
    lines = compare.headline_table(summary)
    assert lines[0] == ("| estimator | track, PID, flat | PID, disturbed | PPO, flat | PPO, disturbed | "
                        "waypoints, PID, flat | PID, disturbed | PPO, flat | PPO, disturbed |")
    assert [ln.split(" | ")[0] for ln in lines[2:]] == ["| `truth`", "| `ekf`", "| `gyro`"]
    truth, ekf, gyro = (ln.split(" | ") for ln in lines[2:])
    assert truth[1].startswith("3.35 [") and truth[5].startswith("100 % [")
    assert ekf[1].startswith("+0.50 [+0.50, +0.50]") and ekf[1].endswith("*") and ekf[5].startswith("0 pp [")
    assert gyro[5].startswith("-50 pp [") and "ppo-truth" not in "".join(lines)
    compare.write_outputs(rows, summary, tmp_path, log=lambda *a: None)
    assert (tmp_path / "headline.md").read_text().splitlines() == lines
    assert "\n".join(lines) in (tmp_path / "summary.md").read_text()
    assert compare.headline_table([r for r in summary if r["estimator"] != "truth"]) == []


def test_plan_finds_the_shipped_policies_and_hashes_their_statistics(tmp_path):
    """Every shipped policy gives its PPO cells (the statistics are .vecnormalize.npz since
    the safe-loading change; plan looked for the old .pkl and skipped every PPO cell), and
    the content hash covers the statistics, so new statistics are a new cache key."""
    import shutil
    from controllers import rl
    msgs = []
    jobs = compare.plan(["track"], ["flat"], ["truth", "ekf"], ["ppo", "ppo-truth"], 1, 0, log=msgs.append)
    assert not msgs, msgs
    assert sorted(j["controller"] for j in jobs) == ["ppo", "ppo", "ppo-truth", "ppo-truth"]
    stem = rl.POLICY_DIR / "ppo-track-ekf"
    for s in (".zip", rl.NORM_SUFFIX, ".json"):
        shutil.copy(str(stem) + s, tmp_path / ("ppo-track-ekf" + s))
    sha = compare.plan(["track"], ["flat"], ["ekf"], ["ppo"], 1, 0, policy_dir=tmp_path)[0]["policy_sha"]
    st = dict(np.load(tmp_path / ("ppo-track-ekf" + rl.NORM_SUFFIX)))
    st["obs_mean"] = st["obs_mean"] + 1.0
    np.savez(tmp_path / ("ppo-track-ekf" + rl.NORM_SUFFIX), **st)
    assert compare.plan(["track"], ["flat"], ["ekf"], ["ppo"], 1, 0, policy_dir=tmp_path)[0]["policy_sha"] != sha


def test_code_version_covers_subpackages(tmp_path, monkeypatch):
    """A source file in a subfolder of a package (envs/tasks/track.py, say) is part of the
    code version: changing it must not let the cache reuse cells of the old code."""
    for pkg in compare.PACKAGES:
        (tmp_path / pkg / "sub").mkdir(parents=True)
        (tmp_path / pkg / "a.py").write_text("x = 1\n")
        (tmp_path / pkg / "sub" / "b.py").write_text("y = 1\n")
    monkeypatch.setattr(compare, "PACKAGE_ROOT", tmp_path)
    v0 = compare.code_version()
    (tmp_path / "envs" / "sub" / "b.py").write_text("y = 2\n")
    v1 = compare.code_version()
    assert v1 != v0
    (tmp_path / "envs" / "sub" / "__pycache__").mkdir()
    (tmp_path / "envs" / "sub" / "__pycache__" / "b.py").write_text("stale\n")
    assert compare.code_version() == v1          # caches and build products do not count


def test_cli_no_cell_to_run_is_an_error(tmp_path, capsys, monkeypatch):
    """A grid whose every cell is skipped (no policy in --policy-dir) is refused before any
    work, not run as an empty grid that writes empty tables and exits 0."""
    monkeypatch.setattr(compare, "run_grid", lambda *a, **k: pytest.fail("work started"))
    out = tmp_path / "out"
    assert compare.main(["--controllers", "ppo", "--estimators", "truth,ekf", "--policy-dir", str(tmp_path),
                         "--out", str(out), "--no-progress"]) == 2
    assert "no cell" in capsys.readouterr().err
    assert not (out / "summary.md").exists()


def test_outputs_are_replaced_whole(tmp_path):
    """A write that fails part way (here a value that cannot be printed, in the last row)
    leaves the previous episodes.csv, summary.csv and summary.md, not a truncated file."""
    rows = [dict(task="track", scenario="flat", estimator=e, controller="pid", episode_seed=s, heading_ss=1.0 + s,
                 speed_ss=0.1, settle_time=1.0, attitude_error=1.0, tilt_error=0.5, heading_est_error=1.0, steps=10)
            for e in ("truth", "ekf") for s in range(3)]
    out = compare.write_outputs(rows, compare.summarise(rows), tmp_path, log=lambda *a: None)
    before = {f: (out / f).read_bytes() for f in ("episodes.csv", "summary.csv", "summary.md")}

    class Unprintable(float):
        def __str__(self):
            raise RuntimeError("disk full")
        __repr__ = __str__
    bad = [dict(r) for r in rows]
    bad[-1]["steps"] = Unprintable(1.0)
    with pytest.raises(RuntimeError, match="disk full"):
        compare.write_outputs(bad, compare.summarise(rows), tmp_path, log=lambda *a: None)
    assert {f: (out / f).read_bytes() for f in before} == before
    assert not [p.name for p in out.iterdir() if "tmp" in p.name]       # no temporary left


def test_a_rerun_removes_the_files_it_does_not_make(tmp_path):
    """A rerun into the same folder without truth kept the earlier run's headline.md and
    headline.png, which then read as this run's."""
    rows = [dict(task="track", scenario="flat", estimator=e, controller="pid", episode_seed=s, heading_ss=1.0 + s,
                 speed_ss=0.1, settle_time=1.0, attitude_error=1.0, tilt_error=0.5, heading_est_error=1.0, steps=10)
            for e in ("truth", "ekf") for s in range(3)]
    compare.write_outputs(rows, compare.summarise(rows), tmp_path, log=lambda *a: None)
    assert (tmp_path / "headline.md").is_file() and (tmp_path / "headline.png").is_file()
    no_truth = [r for r in rows if r["estimator"] != "truth"]
    compare.write_outputs(no_truth, compare.summarise(no_truth), tmp_path, log=lambda *a: None)
    assert not (tmp_path / "headline.md").exists() and not (tmp_path / "headline.png").exists()


def test_cli_restores_the_callers_sigterm_handler():
    """main() turns SIGTERM into an orderly exit while it runs; called from a program (a
    notebook, a test, a service with its own handler) it puts the caller's handler back."""
    import signal

    def mine(*_):
        pass
    old = signal.signal(signal.SIGTERM, mine)
    try:
        assert compare.main(["--estimators", "truth,kalman"]) == 2
        assert signal.getsignal(signal.SIGTERM) is mine
    finally:
        signal.signal(signal.SIGTERM, old)


def test_job_policy_in_working_dir_is_not_shadowed_by_a_shipped_one(tmp_path, monkeypatch):
    """A Ray task reads its policy from the working_dir (policy_dir "."): a policy there with
    the name of a shipped one is the one loaded, even where the package's own policies are
    present (a bare name resolved to the shipped policy first)."""
    from controllers import rl
    seen = []
    real = rl.load_policy
    monkeypatch.setattr(rl, "load_policy", lambda path, **kw: seen.append(Path(path)) or real(path, **kw))
    for s in (".zip", rl.NORM_SUFFIX, ".json"):
        (tmp_path / ("ppo-track-gyro" + s)).write_bytes((rl.POLICY_DIR / ("ppo-track-gyro" + s)).read_bytes())
    monkeypatch.chdir(tmp_path)
    job = compare.plan(["track"], ["flat"], ["gyro"], ["ppo"], episodes=1, seed=0, log=lambda *a: None)[0]
    job = dict(job, policy_dir=".")
    job["env_kwargs"].update(SHORT)
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        compare.run_job(job)
    assert rl._resolve(seen[0])[1].resolve() == (tmp_path / "ppo-track-gyro.zip").resolve()


def test_robot_option_reaches_the_environment(tmp_path, monkeypatch):
    from envs.sphere import SphereRobotEnv
    with pytest.raises(ValueError, match="unknown robot 'moon'.*accepted: realistic, ideal"):
        compare.plan(["track"], ["flat"], ["truth"], ["pid"], 1, 0, robot="moon")
    default = compare.plan(["track"], ["flat"], ["truth"], ["pid"], 1, 0)
    ideal = compare.plan(["track"], ["flat"], ["truth"], ["pid"], 1, 0, robot="ideal")
    assert default[0]["env_kwargs"]["realism"] == "real"       # the environment's default, as before
    assert ideal[0]["env_kwargs"]["realism"] == "ideal"
    assert compare.cell_key(default[0], "v") != compare.cell_key(ideal[0], "v")
    for jobs, vib in ((default, 0.5), (ideal, 0.0)):
        env = SphereRobotEnv(**jobs[0]["env_kwargs"])
        assert env.realism == jobs[0]["env_kwargs"]["realism"] and env.robot.vib_motor == vib
        env.close()
    # a 1-episode cell on each robot: the vibration and the losses change the run
    rows = {}
    for jobs in (default, ideal):
        jobs[0]["env_kwargs"].update(SHORT)
        rows[jobs[0]["env_kwargs"]["realism"]] = compare.run_job(jobs[0])[0]
    assert rows["real"]["speed_ss"] != rows["ideal"]["speed_ss"]
    # the command line passes it through
    class Stop(Exception):
        pass

    def fake_grid(jobs, **kw):
        seen["jobs"] = jobs
        raise Stop

    seen = {}
    monkeypatch.setattr(compare, "run_grid", fake_grid)
    with pytest.raises(Stop):
        compare.main(["--robot", "ideal", "--estimators", "truth", "--controllers", "pid", "--out", str(tmp_path)])
    assert {j["env_kwargs"]["realism"] for j in seen["jobs"]} == {"ideal"}
    with pytest.raises(SystemExit) as e:              # argparse's choices
        compare.main(["--robot", "v2", "--out", str(tmp_path)])
    assert e.value.code == 2
    assert "--robot {realistic,ideal}" in compare._parser().format_help()


def test_paired_between(tmp_path):
    rows = []
    for est, shift, fail in (("ekf", 0.0, ()), ("iir-ekf", 1.5, (2,))):
        for s in range(6):
            rows.append({"task": "waypoints", "scenario": "flat", "estimator": est, "controller": "pid",
                         "episode_seed": s, "success": 0.0 if s in fail else 1.0, "time_to_goal": 10.0 + s + shift,
                         "cross_track": 0.1 * s, "attitude_error": 1.0 + shift, "tilt_error": 0.5 - 0.1 * shift,
                         "heading_est_error": 2.0})
    rows.append(dict(rows[0], estimator="ekf", episode_seed=99))     # no partner: left out
    (d,) = compare.paired_between(rows, "iir-ekf", "ekf")
    assert (d["task"], d["scenario"], d["controller"], d["n"]) == ("waypoints", "flat", "pid", 6)
    assert d["delta_time_to_goal"] == pytest.approx(1.5) and d["delta_time_to_goal_lo"] == pytest.approx(1.5)
    assert d["delta_cross_track"] == 0.0 and d["delta_heading_est_error"] == 0.0
    assert d["delta_tilt_error"] == pytest.approx(-0.15)
    assert d["delta_success"] == pytest.approx(-1 / 6) and d["delta_success_lo"] < -1 / 6 < d["delta_success_hi"]
    # the same from episodes.csv (numbers as text)
    path = tmp_path / "episodes.csv"
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    with open(path) as f:
        (e,) = compare.paired_between(list(csv.DictReader(f)), "iir-ekf", "ekf")
    assert e.keys() == d.keys()
    assert all(e[k] == (v if isinstance(v, str) else pytest.approx(v)) for k, v in d.items())
    with pytest.raises(ValueError, match="estimator 'ukf' is not in the rows; they hold: ekf, iir-ekf"):
        compare.paired_between(rows, "ukf", "ekf")


def test_figures_are_written_atomically(tmp_path, monkeypatch):
    """headline.png and paths.png: a save that fails halfway keeps the previous file whole
    (they were written by a plain savefig, which truncates it first)."""
    import matplotlib.figure
    rows = [dict(dict.fromkeys(compare.SHOWN["track"], 1.0), task="track", scenario="flat", estimator=est,
                 controller="pid", episode_seed=i, heading_ss=h + 0.1 * i)
            for est, h in (("truth", 1.0), ("gyro", 3.0)) for i in range(4)]
    summary = compare.summarise(rows)
    path_rows = [dict(task="track", scenario="flat", episode_seed=0, estimator="gyro", controller="pid",
                      start=np.zeros(2), waypoints=None, path=np.array([[0.0, 0.0], [1.0, 1.0]]))]
    head, paths = tmp_path / "headline.png", tmp_path / "paths.png"
    assert compare._plot_headline(summary, head) is None
    compare._plot_paths(path_rows, paths)
    before = {p: p.read_bytes() for p in (head, paths)}
    assert all(b.startswith(b"\x89PNG") for b in before.values())

    def broken(self, fname, *a, **k):
        if hasattr(fname, "write"):
            fname.write(b"partial")
        else:
            Path(fname).write_bytes(b"partial")
        raise OSError("disk full")
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", broken)
    for call in (lambda: compare._plot_headline(summary, head), lambda: compare._plot_paths(path_rows, paths)):
        with pytest.raises(OSError, match="disk full"):
            call()
    assert {p: p.read_bytes() for p in (head, paths)} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["headline.png", "paths.png"]    # no temporary left


def test_code_version_covers_the_build_and_the_libraries(tmp_path, monkeypatch):
    """The compiled kernels imported (another build, FUSION_MARCH say) and the versions of
    pybullet, torch, stable-baselines3, ... are part of the code version; the same build
    gives the same version in every run."""
    import subprocess
    import sys
    from importlib import metadata
    import importlib.machinery
    # every extension module of the packages, found without their .pyx (a wheel has none)
    built = {f.name for pkg in compare.PACKAGES for f in (compare.PACKAGE_ROOT / pkg).iterdir()
             if f.name.endswith(importlib.machinery.EXTENSION_SUFFIXES[0])}
    assert len(built) > 10 and {f.name for f in compare._kernel_files()} == built
    v0 = compare.code_version()
    assert compare.code_version() == v0
    run = subprocess.run([sys.executable, "-c", "from controllers import compare; print(compare.code_version())"],
                         capture_output=True, text=True, cwd=compare.PACKAGE_ROOT, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.split()[-1] == v0                 # another process, the same build
    import fusion._core as kernel
    other = tmp_path / Path(kernel.__file__).name
    other.write_bytes(Path(kernel.__file__).read_bytes() + b"\0")     # a kernel built otherwise
    monkeypatch.setattr(kernel, "__file__", str(other))
    assert compare.code_version() != v0
    monkeypatch.undo()
    assert compare.code_version() == v0
    real = metadata.version
    for dist in ("pybullet", "torch", "stable-baselines3"):
        monkeypatch.setattr(metadata, "version", lambda d, dist=dist: "0.0.1" if d == dist else real(d))
        assert compare.code_version() != v0, dist
    monkeypatch.undo()


def test_cli_a_corrupt_policy_is_refused_before_the_grid(tmp_path, capsys, monkeypatch):
    """A corrupt policy in --policy-dir failed with a traceback in the middle of the grid; it
    is read before any cell runs. --backend local with --address (which joins Ray) is refused."""
    from controllers.rl import POLICY_DIR
    monkeypatch.setattr(compare, "run_grid", lambda *a, **k: pytest.fail("work started"))
    for f in POLICY_DIR.glob("ppo-track-truth.*"):
        (tmp_path / f.name).write_bytes(f.read_bytes())
    (tmp_path / "ppo-track-truth.zip").write_bytes(b"PK\x03\x04 not a zip")
    assert compare.main(["--tasks", "track", "--scenarios", "flat", "--controllers", "ppo", "--estimators",
                         "truth", "--policy-dir", str(tmp_path), "--out", str(tmp_path / "out"),
                         "--no-progress"]) == 2
    assert "ppo-track-truth" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        compare.main(["--backend", "local", "--address", "auto"])
    assert e.value.code == 2 and "--address" in capsys.readouterr().err


def test_plan_names_policies_trained_with_other_estimator_parameters(tmp_path):
    """A policy's JSON records the estimator parameters it trained with (rl.estimator_config);
    the comparison names a policy whose record differs from the current defaults (its rows
    would evaluate a filter it was not trained with) and those that record none."""
    import json
    import shutil

    from controllers.rl import POLICY_DIR, estimator_config
    for name in ("ppo-track-ekf", "ppo-track-mahony"):
        for suffix in (".zip", ".vecnormalize.npz", ".json"):
            shutil.copy(POLICY_DIR / (name + suffix), tmp_path / (name + suffix))
    meta = json.loads((tmp_path / "ppo-track-ekf.json").read_text())
    meta["estimator_params"] = dict(estimator_config("ekf"), rest_bias_gate=0.0)
    (tmp_path / "ppo-track-ekf.json").write_text(json.dumps(meta))
    meta = json.loads((tmp_path / "ppo-track-mahony.json").read_text())
    meta.pop("estimator_params", None)
    (tmp_path / "ppo-track-mahony.json").write_text(json.dumps(meta))
    logs = []
    compare.plan(["track"], ["flat"], ["ekf", "mahony"], ["ppo"], 2, 0, policy_dir=tmp_path, log=logs.append)
    assert any("ppo-track-ekf was trained with other estimator parameters" in m and "rest_bias_gate" in m
               for m in logs), logs
    assert any("record no estimator parameters" in m and "ppo-track-mahony" in m for m in logs), logs
