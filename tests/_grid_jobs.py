"""Stand-in jobs for the training grid's pool (tests/test_train_grid.py): they run in the
pool's worker processes, so they live in a module those can import."""
import sys
import time
from pathlib import Path


def sleeping_job(job):
    """Marks ``<stem>.started``; runs ``seconds`` s (negative: fails after -seconds); on Ctrl-C
    takes 1 s to 'save a checkpoint' (``<stem>.ckpt``), as a large model or SAC's buffer may,
    or (``save_fails``) raises OSError while saving."""
    Path(job["stem"] + ".started").write_text("")
    if job["seconds"] < 0:
        time.sleep(-job["seconds"])
        raise ValueError("job failed")
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < job["seconds"]:
            time.sleep(0.05)
        return {"stem": job["stem"]}
    except KeyboardInterrupt:
        time.sleep(1.0)
        if job.get("save_fails"):
            raise OSError("disk full while saving") from None
        Path(job["stem"] + ".ckpt").write_text("")
        raise


if __name__ == "__main__":      # driver: <folder> <seconds per job>...
    sys.path.insert(0, str(Path(__file__).parent))
    from controllers import train_grid
    import _grid_jobs
    # SECONDS or SECONDS:save_fails per job
    jobs = [dict(stem=f"{sys.argv[1]}/job{i}", seconds=float(s.split(":")[0]), save_fails=s.endswith(":save_fails"))
            for i, s in enumerate(sys.argv[2:])]
    train_grid._run_local(jobs, 2, lambda j, r: None, job_fn=_grid_jobs.sleeping_job,
                          log=lambda m: print(m, file=sys.stderr, flush=True))
