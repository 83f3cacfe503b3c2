"""Training as a grid: one job per (task, estimator, training seed), on the comparison's
backends (``local``: a process pool; ``ray``: tasks in one Ray session, ``address`` joins an
existing cluster, the packages travel by content: ``controllers.compare.runtime_env``).

Every job writes the policy ``<out>/<algo>-<task>-<estimator>[-seed<s>]`` (``rl.policy_stem``)
with its JSON (the final evaluation in it) and its work directory. With ``resume``, a job
whose JSON has its final evaluation is skipped, and (local backend) a job interrupted with
checkpoints continues from the newest one; without ``resume`` a grid refuses to start over
earlier results. On Ray a job trains in a temporary folder of the worker and returns its files,
which the driver writes (atomically) into ``out``; its start policy (``init_from``) is sent by
content too, so no job reads a path of the driver.
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from controllers import rl



def grid_jobs(algo, tasks, estimators, seeds, out, timesteps=None, init_from=None, final_episodes=10,
              **train_kwargs) -> list[dict]:
    """The jobs of the grid ``tasks`` x ``estimators`` x ``seeds``. ``timesteps``: an int, or a
    dict task -> int (None: the YAML file's). ``init_from``: None, ``"pid"``, or a policy name
    or path in which ``{task}``, ``{estimator}`` and ``{seed}`` are replaced per job.
    ``train_kwargs``: more arguments of ``rl.train`` (n_envs, eval_freq, env_kwargs, ...)."""
    jobs = []
    for task in tasks:
        for est in estimators:
            for seed in seeds:
                n = timesteps.get(task) if isinstance(timesteps, dict) else timesteps
                start = None if init_from is None else _start_for(init_from, task, est, seed)
                jobs.append(dict(train_kwargs, algo=algo, task=task, estimator=est, seed=seed, timesteps=n,
                                 init_from=start, final_episodes=final_episodes,
                                 stem=str(rl.policy_stem(algo, task, est, out, seed))))
    return jobs


def _start_for(template, task, estimator, seed):
    """``init_from`` with ``{task}``, ``{estimator}`` and ``{seed}`` replaced; a ValueError
    naming the template where it holds another field or a stray brace."""
    import string
    if template == rl.TEACHER:
        return template
    rule = ("a grid's start policy may name {task}, {estimator} and {seed}, no other field (a literal brace is "
            "written twice)")

    def fields(text):           # every field, those nested in a format spec too
        for _, f, spec, _ in string.Formatter().parse(text):
            if f is not None:
                yield f
            if spec:
                yield from fields(spec)
    try:
        other = sorted(set(fields(template)) - {"task", "estimator", "seed"})
        if not other:
            return template.format(task=task, estimator=estimator, seed=seed)
    except (KeyError, IndexError, AttributeError, TypeError, ValueError) as e:
        raise ValueError(f"init_from {template!r}: {type(e).__name__} {e}; {rule}") from None
    raise ValueError(f"init_from {template!r} names {', '.join(map(repr, other))}; {rule}")


def _published(job):
    """The job's published JSON as a dict, or None (not written, unreadable)."""
    try:
        meta = json.loads(Path(job["stem"] + ".json").read_text())
    except (OSError, ValueError):
        return None
    return meta if isinstance(meta, dict) else None


def job_done(job, meta=None) -> bool:
    """Whether the job's JSON (``meta``, read if not given) is written with its final
    evaluation (when it has one), by a training to this job's timesteps with its settings
    (settings_differ; run_train_grid refuses a job whose settings differ before any work)."""
    meta = _published(job) if meta is None else meta
    return (meta is not None and (job["final_episodes"] == 0 or "final_evaluation" in meta)
            and meta.get("timesteps") == _resolved(job)[2]
            and not settings_differ(job, meta))


def _resolved(job):
    """(hyperparameters, n_envs, timesteps) the job trains with: its overrides on the YAML
    file's, and the file's n_envs and n_timesteps where the job gives none (rl.run_size)."""
    hp = rl._run_hyperparams(job["algo"], job["task"], job.get("hyperparams_override"))[1]
    timesteps, n_envs = rl.run_size(hp, job.get("timesteps"), job.get("n_envs"))
    return hp, n_envs, timesteps


def settings_differ(job, meta) -> list[str]:
    """The settings of ``job`` that its published JSON ``meta`` does not record, of those a
    resume may not change (a run's identity, as rl's): seed, environment arguments, every
    hyperparameter as resolved (the YAML file's with the overrides: before, only the entries
    overridden now were compared, and a run trained with an override was taken for done
    without it), n_envs, the start policy. A job with more timesteps is not done, and its run
    continues to them, as a single run's resume."""
    out = []
    if job.get("seed") is not None and meta.get("seed") != job["seed"]:
        out.append(f"seed {meta.get('seed')!r} recorded, {job['seed']!r} now")
    if json.loads(json.dumps(job.get("env_kwargs") or {})) != (meta.get("env_kwargs") or {}):
        out.append(f"env_kwargs {meta.get('env_kwargs')!r} recorded, {job.get('env_kwargs')!r} now")
    hp, n_envs, _ = _resolved(job)
    rec = meta.get("hyperparams") or {}
    cloned = str(meta.get("init_from") or "").startswith(rl.TEACHER)
    for k in sorted(set(hp) | set(rec)):
        if cloned and k == "learning_starts":       # (a SAC clone records the 0 it sets)
            continue
        if json.loads(json.dumps(hp.get(k))) != rec.get(k):
            out.append(f"hyperparameter {k} {rec.get(k)!r} recorded, {hp.get(k)!r} now")
    if meta.get("n_envs") != n_envs:
        out.append(f"n_envs {meta.get('n_envs')!r} recorded, {n_envs!r} now")
    init, rec = job.get("init_from"), meta.get("init_from")
    if init is None or rec is None:
        same = init is None and rec is None
    elif init == rl.TEACHER:
        same = str(rec).startswith(rl.TEACHER)
    else:
        same = Path(str(rec)).name.removesuffix(".zip") == Path(str(init)).name.removesuffix(".zip")
    if not same:
        out.append(f"init_from {rec!r} recorded, {init!r} now")
    return out


def _started(job):
    return Path(job["stem"] + ".json").exists() or rl._latest_checkpoint(Path(job["stem"] + ".run") /
                                                                         "checkpoints") is not None


def run_train_job(job, log=None) -> dict:
    """Train one job (``rl.train``, then ``rl.final_evaluation``); returns {"stem": ...}, and
    with ``job["portable"]`` (a Ray task) trains in a temporary folder and returns its files'
    bytes as well (``files``: suffix -> bytes)."""
    keys = ("timesteps", "seed", "env_kwargs", "n_envs", "eval_freq", "checkpoint_freq", "eval_episodes",
            "bc_steps", "hyperparams_override", "trusted", "vec_env", "command")
    kw = {k: job[k] for k in keys if k in job}
    if not job.get("portable"):
        stem = Path(job["stem"])
        resume = rl._latest_checkpoint(Path(str(stem) + ".run") / "checkpoints") is not None
        _train_and_evaluate(job, stem, job["init_from"], resume, kw, log)
        return {"stem": str(stem)}
    with tempfile.TemporaryDirectory(prefix="spherebot-train-") as tmp:
        init = job["init_from"]
        if job.get("init_files"):       # the start policy, sent by content
            init = os.path.join(tmp, "init", "start")
            os.makedirs(os.path.dirname(init))
            for suffix, data in job["init_files"].items():
                Path(init + suffix).write_bytes(data)
            kw["trusted"] = True        # the driver read it under its own trust setting
        stem = Path(tmp) / Path(job["stem"]).name
        _train_and_evaluate(job, stem, init, False, kw, log)
        if job.get("init_files"):       # the JSON names the start the driver sent, not its copy
            meta_path = Path(str(stem) + ".json")
            meta = json.loads(meta_path.read_text())
            meta["init_from"] = Path(str(job["init_from"])).name.removesuffix(".zip") + ".zip"
            meta_path.write_text(json.dumps(meta, indent=2))
        return {"stem": job["stem"], "files": _job_files(stem)}


def _train_and_evaluate(job, stem, init_from, resume, kw, log):
    """rl.train, then the final evaluation into the JSON; the log goes to ``<stem>.log``
    unless ``log`` is given."""
    stem.parent.mkdir(parents=True, exist_ok=True)
    with open(str(stem) + ".log", "a") as f:
        log = log or (lambda *a: print(*a, file=f, flush=True))
        rl.train(job["algo"], job["task"], job["estimator"], out=stem, init_from=None if resume else init_from,
                 resume=resume, progress=False, log=log, **kw)
        if job["final_episodes"] > 0:
            summary = rl.final_evaluation(stem, job["task"], job["estimator"], job.get("env_kwargs"),
                                          job["final_episodes"])
            log("final evaluation:", ", ".join(f"{k} {v:.3g}" for k, v in summary.items()))


def _job_files(stem):
    """suffix -> bytes of what a finished job returns from a Ray worker: the policy's three
    files, its log, and of the work directory the evaluation and Monitor logs (the training
    curves), not the checkpoints."""
    stem = Path(stem)
    run = Path(str(stem) + ".run")
    paths = [Path(str(stem) + s) for s in (".zip", rl.NORM_SUFFIX, ".json", ".log")]
    paths += [run / "evaluations.npz", run / "best.json"] + sorted((run / "monitor").glob("*.csv"))
    return {str(p)[len(str(stem)):]: p.read_bytes() for p in paths if p.is_file()}


def _portable(job):
    """The job for a Ray worker: the start policy's files by content (a shipped name or a path
    of the driver), the output by name only."""
    job = dict(job, portable=True)
    if job["init_from"] not in (None, rl.TEACHER):
        _, zip_path, json_path, vn_path = rl._resolve(job["init_from"])
        job["init_files"] = {s: p.read_bytes() for s, p in ((".zip", zip_path), (".json", json_path),
                                                              (rl.NORM_SUFFIX, vn_path)) if p.is_file()}
        if ".zip" not in job["init_files"]:
            raise FileNotFoundError(f"init_from: policy file {zip_path} does not exist")
    return job


def _write_files(result):
    for suffix, data in result["files"].items():
        path = Path(result["stem"] + suffix)
        path.parent.mkdir(parents=True, exist_ok=True)
        rl.atomic_write(path, lambda f, data=data: f.write(data))


def _run_local(jobs, workers, done, job_fn=None, log=print):
    """The jobs on a pool of ``workers`` processes (``job_fn``: run_train_job; tests pass another)."""
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    job_fn = job_fn or run_train_job
    if workers == 1 or len(jobs) <= 1:
        for j in jobs:
            done(j, job_fn(j))
        return
    ctx = mp.get_context("forkserver")
    stopping = ctx.Event()
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init, initargs=(stopping,))
    todo, running = list(jobs), {}
    try:
        while todo or running:
            # no more jobs submitted than workers: a job queued behind the running ones would
            # start after a Ctrl-C (the pool cannot cancel what it has queued)
            while todo and len(running) < workers:
                j = todo.pop(0)
                running[pool.submit(_pool_job, job_fn, j)] = j
            finished, _ = wait(running, return_when=FIRST_COMPLETED)
            for f in finished:
                done(running.pop(f), f.result())
    except BaseException as e:
        _stop_jobs(pool, running, e, log, stopping)
        raise
    pool.shutdown()


_STOPPING = None        # in a pool worker: the grid's "stopping" event (_worker_init)


def _worker_init(stopping):
    """A pool worker between jobs ignores Ctrl-C (which reaches every process of the terminal's
    group): one that died of it broke the pool, which then terminated the running jobs."""
    import signal
    global _STOPPING
    _STOPPING = stopping
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _pool_job(job_fn, job):
    """A job in a pool worker, Ctrl-C heard once while it runs (rl.train then saves a
    checkpoint, which a second SIGINT, the terminal's or the driver's, must not interrupt).
    A job that starts as the grid stops does not run: its worker, between jobs, ignored the
    SIGINT, and the driver sets the event before it signals."""
    import signal
    signal.signal(signal.SIGINT, _interrupt_once)
    try:
        if _STOPPING is not None and _STOPPING.is_set():
            raise KeyboardInterrupt
        return job_fn(job)
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _interrupt_once(signum, frame):
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise KeyboardInterrupt


#: s a stopping grid waits for its running jobs to save their checkpoints
STOP_WAIT_S = 120.0


def _stop_jobs(pool, running, cause, log, stopping):
    """Ctrl-C, SIGTERM (SystemExit) or a failed job (``cause``): start no other job, and let the
    running ones end as a single run's Ctrl-C ends it, with a checkpoint that --resume
    continues from (before, the driver terminated them at once and lost the work since their
    last periodic checkpoint). Every worker is sent SIGINT: a running job hears it once (the
    terminal's Ctrl-C may have come first), an idle worker ignores it. A Ctrl-C while the jobs
    save ends the wait and terminates them; after a failure, the first Ctrl-C only repeats
    what is under way. An error a job raises while it stops is said, not dropped."""
    import signal
    from concurrent.futures import wait
    procs = list((pool._processes or {}).values())
    interrupted = isinstance(cause, (KeyboardInterrupt, SystemExit))
    spare = 0 if interrupted else 1
    try:
        stopping.set()
        for proc in procs:
            try:
                os.kill(proc.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
        pool.shutdown(wait=False, cancel_futures=True)
        left, said = [f for f in running if not f.done()], interrupted
        while True:
            try:
                if not said:
                    said = True
                    log(f"a job failed ({type(cause).__name__}: {cause}); the running ones save a checkpoint "
                        f"and stop")
                left = list(wait(left, timeout=STOP_WAIT_S).not_done) if left else []
                break
            except KeyboardInterrupt:
                if not spare:
                    raise
                spare -= 1
                log("stopping: the running jobs are saving their checkpoints (Ctrl-C again to kill them)")
        for f, job in running.items():
            e = f.exception() if f.done() and not f.cancelled() else None
            if e is not None and not isinstance(e, KeyboardInterrupt):
                log(f"job {job['stem']} raised {type(e).__name__}: {e} while the grid stopped")
    finally:
        for proc in procs:
            if proc.is_alive():
                proc.terminate()


def _run_ray(jobs, address, workers, done):
    from controllers.compare import ray_session
    portable = [_portable(j) for j in jobs]
    # a job's environments are processes of their own: it takes their CPUs
    cpus = [max(1, _resolved(j)[1]) for j in jobs]
    with ray_session(address, workers) as ray:
        have = ray.cluster_resources().get("CPU", 0)
        if address is None and max(cpus) > have:       # (a task no node can take waits for ever)
            raise ValueError(f"a job of the grid runs {max(cpus)} environments, one CPU each, and the local Ray "
                             f"cluster has {have:g} CPUs: --workers {max(cpus)} or more, or --n-envs {int(have)}")
        refs = {}
        for j, pj, n in zip(jobs, portable, cpus):
            remote = ray.remote(num_cpus=n)(run_train_job)
            refs[remote.remote(pj)] = j
        pending = list(refs)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for r in ready:
                result = ray.get(r)
                _write_files(result)
                done(refs[r], result)


def run_train_grid(jobs, backend="local", workers=None, address=None, resume=False, install=False,
                   log=print) -> list[str]:
    """Run the jobs not finished yet; returns every job's stem. ``install``: each finished
    job's policy is copied into the package (``rl.install_policy``, under its stem's name)."""
    if backend not in ("local", "ray"):
        raise ValueError(f"unknown backend {backend!r}; accepted: local, ray")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers must be None or an integer >= 1, got {workers!r}")
    if len({j["stem"] for j in jobs}) != len(jobs):
        raise ValueError("two jobs of the grid write the same policy")
    started = [j["stem"] for j in jobs if _started(j)]
    if started and not resume:
        raise FileExistsError(f"{len(started)} jobs of this grid have results or checkpoints already (e.g. "
                              f"{started[0]}): resume=True (--resume) to continue the grid")
    metas = [_published(j) for j in jobs]
    for j, meta in zip(jobs, metas):
        diff = settings_differ(j, meta) if meta is not None else []
        if diff:
            raise ValueError(f"--resume: {j['stem']} was trained with other settings ({'; '.join(diff)}); "
                             f"resume the grid with its own settings, or train into another --out")
    todo = [j for j, meta in zip(jobs, metas) if meta is None or not job_done(j, meta)]
    log(f"training grid: {len(jobs) - len(todo)} of {len(jobs)} jobs finished already, {len(todo)} to run "
        f"({backend})")

    def done(job, result):
        log(f"finished {job['stem']}")
        if install:
            log(f"installed: {rl.install_policy(job['stem'])}")

    if install:
        for j in jobs:
            if j not in todo:
                done(j, None)
    if todo and backend == "local":
        _run_local(todo, workers or max(1, (os.cpu_count() or 2) // 2), done, log=log)
    elif todo:
        _run_ray(todo, address, workers, done)
    return [j["stem"] for j in jobs]
