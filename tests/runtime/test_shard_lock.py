"""A shard is taken with an exclusive create (runtime/shards.py): two jobs of one shard started at the same
instant never both run; the lock goes when the job ends, finished or failed (issue 26, case 7)."""

import json
import threading

import pytest

from trioman.runtime.shards import Shard, shard_run


def test_two_jobs_of_one_shard_started_together_run_once(tmp_path):
    shard, jobs = Shard(1, 3), 8
    barrier, inside, refused = threading.Barrier(jobs), [], []
    release = threading.Event()

    def job(k):
        barrier.wait()  # every job tries to take the shard at the same instant
        try:
            with shard_run(tmp_path, shard, {"seed": 1}, ["b"]):
                inside.append(k)
                release.wait(5)
        except ValueError as err:
            refused.append(str(err))

    threads = [threading.Thread(target=job, args=(k,)) for k in range(jobs)]
    for t in threads:
        t.start()
    for _ in range(500):  # until every job has entered or been refused (at most 5 s)
        if len(inside) + len(refused) == jobs:
            break
        threading.Event().wait(0.01)
    release.set()
    for t in threads:
        t.join(10)
    assert len(inside) == 1 and len(refused) == jobs - 1
    lock = tmp_path / "shards" / "1-of-3.lock"
    assert all(r.startswith("shard 1/3: another job of this shard is running (") and str(lock) in r for r in refused)
    assert not lock.exists()  # released at the end
    assert json.loads((tmp_path / "shards" / "1-of-3.json").read_text())["status"] == "complete"


def test_a_failed_job_releases_its_shard_and_a_killed_one_is_named(tmp_path):
    shard = Shard(0, 2)
    with pytest.raises(RuntimeError, match="boom"):
        with shard_run(tmp_path, shard, {}, ["a"]):
            raise RuntimeError("boom")
    with shard_run(tmp_path, shard, {}, ["a"]):  # taken again
        pass
    lock = tmp_path / "shards" / "0-of-2.lock"
    import socket

    lock.write_text(json.dumps({"host": socket.gethostname(), "pid": 2**22 + 12345, "started": 0}))  # no such process
    with pytest.raises(ValueError, match=rf"another job of this shard was killed \(that process is gone\) .*remove {lock}"):
        with shard_run(tmp_path, shard, {}, ["a"]):
            pass
    assert lock.exists()  # the refused job leaves the lock to its owner
