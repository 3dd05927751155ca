"""Stage timing: marks (nothing recorded outside a record, nested stages counted once) and the printed stage
lines with their peak RSS."""

import mmap
import re
import sys
import time

import numpy as np
import pytest
from trioman.runtime.stages import StageLog, record_stages, reset_peak_rss, stage


def test_stage_outside_a_record_records_nothing():
    with stage("a"):
        pass
    with record_stages() as record:
        pass
    assert record == {}


def test_nested_stages_exclude_inner_time_and_add_up():
    with record_stages() as record:
        t0 = time.perf_counter()
        with stage("outer"):
            time.sleep(0.02)
            with stage("inner"):
                time.sleep(0.03)
        with stage("inner"):
            time.sleep(0.01)
        wall = time.perf_counter() - t0
    assert list(record) == ["inner", "outer"]
    assert 0.04 <= record["inner"] < 0.04 + 0.02
    assert 0.02 <= record["outer"] < 0.03 + 0.02
    assert abs(record["inner"] + record["outer"] - wall) < 0.005

LINE = re.compile(r"^stage (\S+) +(\d+\.\d) s +peak RSS +(\d+) MiB")
MB = 2**20


def touch_and_unmap(n: int) -> None:
    """Map n fresh bytes, touch every page (resident), unmap them: the RSS rises by n and falls back whatever
    the process's allocator keeps (a freed numpy array may stay resident in its heap)."""
    m = mmap.mmap(-1, n)
    for i in range(0, n, mmap.PAGESIZE):
        m[i] = 1
    m.close()


def test_stage_lines_time_and_peak():
    lines = []
    log = StageLog(say=lines.append)
    with log.stage("alloc"):
        a = np.ones(200 * MB // 8)  # 200 MiB, every page touched
        del a
    with log.stage("idle"):
        pass
    assert [LINE.match(s).group(1) for s in lines] == ["alloc", "idle"]
    alloc, idle = log.stages
    assert alloc.peak_rss >= 200 * MB and alloc.seconds >= 0
    # the log's peak is its stages' highest (a process whose heap already holds 200 MiB free may peak in either)
    assert log.peak_rss == max(alloc.peak_rss, idle.peak_rss) and log.seconds == alloc.seconds + idle.seconds


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the peak is reset through /proc on Linux")
def test_each_stage_has_its_own_peak():
    log = StageLog(say=lambda line: None)
    with log.stage("alloc"):
        touch_and_unmap(200 * MB)
    with log.stage("idle"):
        pass
    assert reset_peak_rss()
    assert log.stages[1].peak_rss < log.stages[0].peak_rss - 150 * MB
