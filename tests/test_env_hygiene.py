"""Resource hygiene of the environment: create/close cycles, vector-env workers that exit
on close and on Ctrl-C. (10,000 resets and 1,000 create/close cycles with memory figures:
benchmarks/env_speed.py.)"""
import gc
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

pytest.importorskip("pybullet")

from benchmarks.env_speed import rss_mb
from envs.sphere import SphereRobotEnv

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="needs /proc")
def test_create_close_cycles_reuse_clients_and_memory():
    import pybullet as p
    ids = []
    for i in range(20):                 # warm-up
        e = SphereRobotEnv(estimator="ekf")
        e.reset(seed=i)
        e.close()
    gc.collect()
    before = rss_mb()
    for i in range(200):
        e = SphereRobotEnv(estimator="ekf")
        e.reset(seed=i)
        e.step([0.3, 0.1])
        ids.append(e._client)
        e.close()
        assert not p.getConnectionInfo(ids[-1])["isConnected"]
    gc.collect()
    growth = rss_mb() - before
    assert len(set(ids)) <= 2, "closed physics clients are not reused: a client leaks"
    assert growth < 20.0, f"memory grew by {growth:.1f} MB over 200 create/close cycles"


def _make():
    return SphereRobotEnv(task="track", estimator="ekf")


def test_subproc_workers_exit_on_close():
    pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.vec_env import SubprocVecEnv
    venv = SubprocVecEnv([_make, _make])
    venv.reset()
    procs = list(venv.processes)
    assert all(pr.is_alive() for pr in procs)
    venv.close()
    for pr in procs:
        pr.join(timeout=10)
        assert not pr.is_alive() and pr.exitcode == 0


@pytest.mark.skipif(sys.platform == "win32", reason="process groups")
def test_ctrl_c_stops_vec_env_workers(tmp_path):
    """The training vector env (controllers.rl.make_vec_env) on Ctrl-C: the main process
    closes its workers cleanly and none is left running."""
    pytest.importorskip("stable_baselines3")
    script = tmp_path / "run.py"
    pids = tmp_path / "pids"
    script.write_text(textwrap.dedent(f"""
        import signal, sys, numpy as np
        # as in a terminal: Ctrl-C raises KeyboardInterrupt (a test runner started in the
        # background may pass SIGINT down as ignored)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        sys.path.insert(0, {str(ROOT)!r})
        from controllers.rl import make_vec_env
        if __name__ == "__main__":
            venv = make_vec_env("track", "ekf", n_envs=2, seed=0)
            venv.reset()
            open({str(pids)!r}, "w").write(" ".join(str(p.pid) for p in venv.processes))
            try:
                while True:
                    venv.step(np.zeros((2, 2), dtype=np.float32))
            except KeyboardInterrupt:
                venv.close()
                print("closed")
    """))
    # a new session = its own process group, as a terminal's foreground job: Ctrl-C goes to all
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True, text=True)
    try:
        t0 = time.time()
        while not pids.exists() and time.time() - t0 < 60:
            time.sleep(0.2)
        assert pids.exists(), "the vector environment did not start"
        time.sleep(1.0)
        workers = [int(x) for x in pids.read_text().split()]
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=30)
        assert proc.returncode == 0 and "closed" in out, err[-2000:]
    finally:
        # never leave the child and its workers running when the test fails
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    time.sleep(0.5)
    for pid in workers:
        alive = os.path.exists(f"/proc/{pid}") and "zombie" not in open(f"/proc/{pid}/status").read().lower()
        assert not alive, f"worker {pid} still running after Ctrl-C"


def test_vec_env_close_after_a_step_interrupted_halfway():
    """Ctrl-C inside ``step_wait`` after the first worker's result was read (the race that
    made SB3's own close wait forever): close returns and every worker exits."""
    pytest.importorskip("stable_baselines3")
    import numpy as np
    from controllers.rl import make_vec_env
    venv = make_vec_env("track", "ekf", n_envs=2, seed=0)
    try:
        venv.reset()
        venv.step_async(np.zeros((2, 2), dtype=np.float32))
        venv.remotes[0].recv()         # what step_wait had read when the interrupt came
        import threading
        closer = threading.Thread(target=venv.close, daemon=True)   # a hang fails, not stalls
        closer.start()
        closer.join(timeout=30)
        assert not closer.is_alive(), "close() hangs after an interrupted step"
        assert not any(p.is_alive() for p in venv.processes)
    finally:
        for p in venv.processes:
            if p.is_alive():
                p.kill()
