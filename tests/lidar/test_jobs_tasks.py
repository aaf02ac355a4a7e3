"""``lidar.jobs.run_tasks``: a module-level function over tasks, serially, in task order, with progress."""

from __future__ import annotations

import pytest

from lidarcat.errors import ProductError
from lidarcat.lidar.jobs import run_tasks


def _square(x: int) -> int:
    if x < 0:
        raise ProductError(f"task {x}: negative")
    return x * x


def test_serial_tasks_keep_their_order_and_report_progress():
    made = []

    def tasks():   # made lazily, one at a time
        for k in range(5):
            made.append(k)
            yield k

    seen = []
    assert run_tasks(_square, tasks(), progress=seen.append) == [0, 1, 4, 9, 16]
    assert made == [0, 1, 2, 3, 4] and seen == [1] * 5


def test_a_task_error_reaches_the_caller_and_stops_the_run():
    done = []
    with pytest.raises(ProductError, match="task -1: negative"):
        run_tasks(_square, [2, -1, 3], progress=done.append)
    assert done == [1]
