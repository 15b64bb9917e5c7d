"""Tests of the interrupt task scheduler against the paper's Table 1 and brute force."""

from __future__ import annotations

import itertools
import math

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from device.scheduler import Schedule, Task, lower_bound, paper_tasks, schedule

# --- the paper's set (Table 1) ---------------------------------------------------------------

# Table 1, interrupts numbered from 1: the tasks besides "duty update" that run at each.
TABLE_1 = {
    1: {"read sensors"},
    2: {"cylinder 1"},
    3: {"cylinder 2"},
    4: {"cylinder 3"},
    5: {"cylinder 4"},
    6: {"cylinder 5"},
    7: {"cylinder 6"},
    8: {"read sensors"},
    15: {"read sensors"},
    22: {"read sensors"},
    29: {"read sensors"},
    30: {"cylinder 1"},
    31: {"cylinder 2"},
}


@pytest.mark.parametrize("exact", [True, False])
def test_paper_set_reproduces_table_1(exact: bool) -> None:
    sched = schedule(paper_tasks(), exact=exact)
    assert [t.name for t in sched.tasks] == [t.name for t in paper_tasks()]
    assert sched.hyperperiod == 28
    assert sched.offsets == (0, 0, 1, 2, 3, 4, 5, 6)
    assert sched.max_tasks_per_interrupt == 2
    for interrupt in range(1, 32):
        names = {sched.tasks[k].name for k in sched.tasks_at(interrupt - 1)}
        expected = {"duty update"} | TABLE_1.get(interrupt, set())
        assert names == expected, f"interrupt {interrupt}"


def test_paper_set_meets_lower_bound() -> None:
    assert lower_bound(paper_tasks()) == 2
    loads = (2,) * 8 + (1,) * 6 + (2,) + (1,) * 6 + (2,) + (1,) * 6  # sensors at 7, 14, 21
    assert schedule(paper_tasks()).loads == loads


def test_table_rendering_matches_paper_layout() -> None:
    text = schedule(paper_tasks()).table()
    lines = text.splitlines()
    assert lines[0].split(" | ")[1:] == [t.name for t in paper_tasks()]
    assert len(lines) == 2 + 28 + 3  # header, rule, one hyperperiod plus 3 rows
    rows = {int(line.split("|")[0]): [c.strip() for c in line.split("|")[1:]] for line in lines[2:]}
    assert rows[1] == ["X", "X", "", "", "", "", "", ""]
    assert rows[7] == ["X", "", "", "", "", "", "", "X"]
    assert rows[30] == ["X", "", "X", "", "", "", "", ""]
    assert rows[31] == ["X", "", "", "X", "", "", "", ""]
    assert len(schedule(paper_tasks()).table(5).splitlines()) == 2 + 5


def test_as_array_agrees_with_tasks_at() -> None:
    sched = schedule(paper_tasks())
    array = sched.as_array()
    assert array.dtype == np.int64
    assert array.shape == (28, 2)
    for tick in range(28):
        row = sched.tasks_at(tick)
        assert tuple(int(k) for k in array[tick, : len(row)]) == row
        assert (array[tick, len(row) :] == -1).all()
    assert array[8].tolist() == [0, -1]


def test_tasks_at_wraps_and_rejects_negative_ticks() -> None:
    sched = schedule(paper_tasks())
    assert sched.tasks_at(28 * 1000 + 3) == sched.tasks_at(3) == (0, 4)
    with pytest.raises(ValueError, match="tick"):
        sched.tasks_at(-1)


# --- greedy versus exact ---------------------------------------------------------------------


def test_branch_and_bound_beats_greedy_where_greedy_is_suboptimal() -> None:
    # Greedy puts the two period-4 tasks at offsets 0 and 1, which leaves every offset of the
    # period-6 task colliding; offsets 0 and 2 leave the odd ticks free for it.
    tasks = [Task("a", 4), Task("b", 4), Task("c", 6)]
    assert schedule(tasks, exact=False).max_tasks_per_interrupt == 2
    assert schedule(tasks, node_limit=0).max_tasks_per_interrupt == 2
    assert schedule(tasks).max_tasks_per_interrupt == 1


def test_results_are_in_input_order() -> None:
    tasks = [Task("slow", 4), Task("fast", 2), Task("every", 1)]
    sched = schedule(tasks)
    assert sched.tasks == tuple(tasks)
    assert sched.offsets[2] == 0  # placed first, at offset 0
    assert sched.offsets[1] == 0  # placed second; every offset collides with "every"
    assert sched.offsets[0] == 1  # the only place not colliding with "fast"
    assert sched.tasks_at(1) == (0, 2)


# --- brute force -----------------------------------------------------------------------------

PERIODS = (1, 2, 3, 4, 6, 8, 12)
# Offsets combinations the brute force enumerates (all of them, with no symmetry reduction).
MAX_COMBINATIONS = 20_000


def brute_force_optimum(periods: tuple[int, ...]) -> int:
    """Smallest max load over every offset combination, vectorised over all of them."""
    hyperperiod = math.lcm(*periods)
    ticks = np.arange(hyperperiod)
    total: npt.NDArray[np.int64] = np.zeros((1,) * len(periods) + (hyperperiod,), np.int64)
    for axis, period in enumerate(periods):
        # runs[o, t] = 1 when a task of this period at offset o runs at tick t.
        runs = (ticks[None, :] % period == np.arange(period)[:, None]).astype(np.int64)
        shape = [1] * len(periods) + [hyperperiod]
        shape[axis] = period
        total = total + runs.reshape(shape)
    return int(total.max(axis=-1).min())


task_periods = st.lists(st.sampled_from(PERIODS), min_size=1, max_size=5).filter(
    lambda ps: math.prod(ps) <= MAX_COMBINATIONS
)


@settings(max_examples=300, deadline=None, database=None)
@given(task_periods)
def test_exact_schedule_matches_brute_force(periods: list[int]) -> None:
    tasks = [Task(f"t{i}", p) for i, p in enumerate(periods)]
    optimum = brute_force_optimum(tuple(periods))
    exact = schedule(tasks)
    greedy = schedule(tasks, exact=False)

    assert exact.max_tasks_per_interrupt == optimum
    assert greedy.max_tasks_per_interrupt >= optimum
    assert lower_bound(tasks) <= optimum
    for sched in (exact, greedy):
        assert sched.tasks == tuple(tasks)
        assert sched.hyperperiod == math.lcm(*periods)
        assert all(0 <= o < t.period for o, t in zip(sched.offsets, tasks, strict=True))
        runs = [0] * len(tasks)
        for tick in range(sched.hyperperiod):
            for k in sched.tasks_at(tick):
                runs[k] += 1
        assert runs == [sched.hyperperiod // t.period for t in tasks]
        assert sum(sched.loads) == sum(runs)
        array = sched.as_array()
        assert array.shape == (sched.hyperperiod, sched.max_tasks_per_interrupt)
        assert ((array >= 0).sum(axis=1) == np.array(sched.loads)).all()


def test_brute_force_helper_knows_a_collision() -> None:
    # Periods 2 and 3 share no common offset class, so they must meet somewhere (CRT).
    assert brute_force_optimum((2, 3)) == 2
    assert brute_force_optimum((2, 2)) == 1
    assert brute_force_optimum((1, 2, 4, 4)) == 2


def test_greedy_ties_prefer_smallest_offset() -> None:
    # Every offset of "b" is equally good, so the smallest wins.
    assert schedule([Task("a", 1), Task("b", 12)]).offsets == (0, 0)
    # With "a" on the even ticks and "b" at 1, 5, 9, offsets 0 and 1 of "c" both reach load 2,
    # but offset 1 lands once on an idle tick (7) instead of twice on busy ones (0, 6).
    assert schedule([Task("a", 2), Task("b", 4), Task("c", 6)], exact=False).offsets == (0, 1, 1)
    assert schedule([Task("a", 4), Task("b", 4)], exact=False).offsets == (0, 1)


# --- invalid input ---------------------------------------------------------------------------


@pytest.mark.parametrize("period", [0, -1, -28, 2.0, 1.5, "7", None, True])
def test_task_rejects_bad_period(period: object) -> None:
    with pytest.raises(ValueError, match="period"):
        Task("bad", period)  # type: ignore[arg-type]


def test_task_rejects_empty_name() -> None:
    with pytest.raises(ValueError, match="name"):
        Task("", 3)


def test_schedule_rejects_empty_task_list() -> None:
    with pytest.raises(ValueError, match="empty"):
        schedule([])
    with pytest.raises(ValueError, match="empty"):
        lower_bound(())


def test_schedule_rejects_bad_node_limit() -> None:
    with pytest.raises(ValueError, match="node_limit"):
        schedule(paper_tasks(), node_limit=-1)


def test_hand_built_schedule_is_validated() -> None:
    tasks = (Task("a", 2), Task("b", 3))
    assert Schedule(tasks, (1, 2), 6).tasks_at(5) == (0, 1)
    with pytest.raises(ValueError, match="offset"):
        Schedule(tasks, (2, 0), 6)
    with pytest.raises(ValueError, match="offsets given"):
        Schedule(tasks, (0,), 6)
    with pytest.raises(ValueError, match="hyperperiod"):
        Schedule(tasks, (0, 0), 12)


def test_brute_force_is_exhaustive_for_small_sets() -> None:
    # Cross-check the vectorised brute force against a plain loop on one set.
    periods = (2, 4, 6)
    hyperperiod = math.lcm(*periods)
    best = min(
        max(
            sum(1 for p, o in zip(periods, offs, strict=True) if t % p == o)
            for t in range(hyperperiod)
        )
        for offs in itertools.product(*(range(p) for p in periods))
    )
    assert brute_force_optimum(periods) == best == 2
