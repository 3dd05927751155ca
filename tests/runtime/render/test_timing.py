"""Stage timers: nothing recorded outside a record, nested stages counted once."""

import time

from trioman.runtime.render.timing import record_stages, stage


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
