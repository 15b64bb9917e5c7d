"""Static offset scheduling of the periodic tasks run by the controller's interrupt handler.

The device controller runs one interrupt handler per tick (1/7000 s).  Every task ``k`` has a
period ``T_k`` in ticks and runs at ticks ``offset_k, offset_k + T_k, ...``; the pattern repeats
every hyperperiod ``H = lcm(T_1, ..., T_N)``.  The time a handler takes is the sum of the tasks it
runs, so to keep the handler's duration as constant (and as short) as possible the offsets are
chosen to minimise the largest number of tasks that share one interrupt.

Following "Control of the Rutgers Ankle Rehabilitation Interface" (section 3), offsets are first
chosen greedily, from the smaller periods to the larger ones.  Because the greedy answer is not
optimal in general, it is compared with a simple lower bound and, when the bound is not met,
improved by a bounded depth-first branch-and-bound search.

The schedule is computed once, off-line; :meth:`Schedule.as_array` hands it to the compiled tick
loop as a dense table.  Nothing here is on the real-time path, so the code favours clarity.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["Schedule", "Task", "lower_bound", "paper_tasks", "schedule"]


@dataclass(frozen=True)
class Task:
    """A periodic job of the interrupt handler.

    ``period`` is counted in interrupts (ticks), so it must be a positive integer: a fractional
    or zero period has no meaning for a handler that can only act on whole ticks.
    """

    name: str
    period: int

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"task name must be a non-empty string, got {self.name!r}")
        # bool is an int subclass, but True as a period is surely a mistake.
        if not isinstance(self.period, int) or isinstance(self.period, bool):
            raise ValueError(
                f"task {self.name!r}: period must be an int (ticks), "
                f"got {type(self.period).__name__} {self.period!r}"
            )
        if self.period < 1:
            raise ValueError(f"task {self.name!r}: period must be >= 1 tick, got {self.period}")


def paper_tasks() -> tuple[Task, ...]:
    """The task set of the paper's Table 1, in the paper's column order.

    The duty cycle of the PWM valves is updated every interrupt, the sensors are read every 7th,
    and each of the six cylinders gets a new control input every 28th.
    """
    return (
        Task("duty update", 1),
        Task("read sensors", 7),
        *(Task(f"cylinder {i}", 28) for i in range(1, 7)),
    )


def _check_tasks(tasks: Sequence[Task]) -> tuple[Task, ...]:
    tasks = tuple(tasks)
    if not tasks:
        raise ValueError("cannot schedule an empty task list")
    for task in tasks:
        if not isinstance(task, Task):
            raise ValueError(f"expected Task instances, got {type(task).__name__} {task!r}")
    return tasks


def _hyperperiod(tasks: Sequence[Task]) -> int:
    return math.lcm(*(task.period for task in tasks))


@dataclass(frozen=True)
class Schedule:
    """Offsets for a task set: task ``k`` runs at every tick ``t`` with ``t % T_k == offset_k``.

    ``tasks`` and ``offsets`` are in the caller's order, so indices returned by
    :meth:`tasks_at` and stored in :meth:`as_array` refer to the caller's task list.
    """

    tasks: tuple[Task, ...]
    offsets: tuple[int, ...]
    hyperperiod: int

    def __post_init__(self) -> None:
        # A Schedule may also be built by hand (e.g. copied from a paper); check that it is
        # consistent, since the tick loop trusts it blindly.
        _check_tasks(self.tasks)
        if len(self.offsets) != len(self.tasks):
            raise ValueError(f"{len(self.offsets)} offsets given for {len(self.tasks)} tasks")
        for task, offset in zip(self.tasks, self.offsets, strict=True):
            if not isinstance(offset, int) or not 0 <= offset < task.period:
                raise ValueError(
                    f"task {task.name!r}: offset must be an int in [0, {task.period}), "
                    f"got {offset!r}"
                )
        expected = _hyperperiod(self.tasks)
        if self.hyperperiod != expected:
            raise ValueError(
                f"hyperperiod must be lcm of the periods ({expected}), got {self.hyperperiod}"
            )

    def tasks_at(self, tick: int) -> tuple[int, ...]:
        """Indices (into ``tasks``, ascending) of the tasks run at interrupt ``tick`` (0-based)."""
        if tick < 0:
            raise ValueError(f"tick must be >= 0, got {tick}")
        tick %= self.hyperperiod
        return tuple(
            k
            for k, (task, offset) in enumerate(zip(self.tasks, self.offsets, strict=True))
            if tick % task.period == offset
        )

    @property
    def loads(self) -> tuple[int, ...]:
        """Number of tasks run at each interrupt of one hyperperiod."""
        return tuple(int(n) for n in _loads(self.tasks, self.offsets, self.hyperperiod))

    @property
    def max_tasks_per_interrupt(self) -> int:
        """The worst-case handler load, which is what the offsets are chosen to minimise."""
        return max(self.loads)

    def as_array(self) -> npt.NDArray[np.int64]:
        """Dense ``(hyperperiod, max_tasks_per_interrupt)`` table of task indices, -1 padded.

        A rectangular int64 array is what a numba-compiled tick loop can index without Python
        objects: row ``tick % hyperperiod`` lists the tasks to run, stopping at the first -1.
        """
        table = np.full((self.hyperperiod, self.max_tasks_per_interrupt), -1, dtype=np.int64)
        for tick in range(self.hyperperiod):
            row = self.tasks_at(tick)
            table[tick, : len(row)] = row
        return table

    def table(self, n_interrupts: int | None = None) -> str:
        """Render the schedule like the paper's Table 1: interrupts numbered from 1, X = runs.

        The default shows one hyperperiod plus 3 rows, so the wrap-around is visible.
        """
        if n_interrupts is None:
            n_interrupts = self.hyperperiod + 3
        if n_interrupts < 0:
            raise ValueError(f"n_interrupts must be >= 0, got {n_interrupts}")
        first = "Interrupt"
        headers = [first, *(task.name for task in self.tasks)]
        widths = [max(len(first), len(str(n_interrupts))), *(len(h) for h in headers[1:])]
        lines = [" | ".join(h.ljust(w) for h, w in zip(headers, widths, strict=True)).rstrip()]
        lines.append("-+-".join("-" * w for w in widths))
        for tick in range(n_interrupts):
            running = set(self.tasks_at(tick))
            cells = [str(tick + 1).rjust(widths[0])]
            cells += [("X" if k in running else "").center(w) for k, w in enumerate(widths[1:])]
            lines.append(" | ".join(cells).rstrip())
        return "\n".join(lines)


def _loads(
    tasks: Sequence[Task], offsets: Sequence[int], hyperperiod: int
) -> npt.NDArray[np.int64]:
    loads = np.zeros(hyperperiod, dtype=np.int64)
    for task, offset in zip(tasks, offsets, strict=True):
        loads[offset :: task.period] += 1
    return loads


def lower_bound(tasks: Sequence[Task]) -> int:
    """A load that no choice of offsets can beat.

    Over one hyperperiod the tasks run ``sum(H / T_k)`` times in ``H`` interrupts, so some
    interrupt carries at least the ceiling of the average (the total utilisation).  Tasks of
    period 1 run at every interrupt whatever their offset; that count is implied by the average
    but is kept explicit as the obviously forced load.
    """
    tasks = _check_tasks(tasks)
    hyperperiod = _hyperperiod(tasks)
    runs = sum(hyperperiod // task.period for task in tasks)
    average = -(-runs // hyperperiod)  # integer ceiling
    every_tick = sum(1 for task in tasks if task.period == 1)
    return max(average, every_tick)


def schedule(tasks: Sequence[Task], *, exact: bool = True, node_limit: int = 200_000) -> Schedule:
    """Choose offsets that minimise the maximum number of tasks per interrupt.

    1. Greedy, as in the paper: tasks by ascending period (ties keep input order); each takes the
       offset giving the lowest resulting maximum load, then the lowest sum of squared loads
       (spreads work evenly, leaving room for later tasks), then the smallest offset.
    2. If that meets :func:`lower_bound` it is optimal and is returned.
    3. Otherwise, if ``exact``, a depth-first branch-and-bound over the offsets (same task order,
       greedy result as incumbent) looks for a better one, visiting at most ``node_limit``
       partial assignments; the best schedule found is returned, optimal if the search finished.
    """
    tasks = _check_tasks(tasks)
    if isinstance(node_limit, bool) or not isinstance(node_limit, int) or node_limit < 0:
        raise ValueError(f"node_limit must be an int >= 0, got {node_limit!r}")
    hyperperiod = _hyperperiod(tasks)
    order = sorted(range(len(tasks)), key=lambda k: tasks[k].period)  # sorted() is stable
    periods = [tasks[k].period for k in order]

    sorted_offsets = _greedy(periods, hyperperiod)
    best = int(_loads([tasks[k] for k in order], sorted_offsets, hyperperiod).max())
    bound = lower_bound(tasks)
    if exact and best > bound:
        sorted_offsets, best = _branch_and_bound(
            periods, hyperperiod, sorted_offsets, best, bound, node_limit
        )

    offsets = [0] * len(tasks)
    for position, k in enumerate(order):
        offsets[k] = sorted_offsets[position]
    return Schedule(tasks=tasks, offsets=tuple(offsets), hyperperiod=hyperperiod)


def _greedy(periods: Sequence[int], hyperperiod: int) -> list[int]:
    """The paper's rule: place each task (in the given order) where it hurts least."""
    loads = np.zeros(hyperperiod, dtype=np.int64)
    offsets: list[int] = []
    for period in periods:
        current_max = int(loads.max())
        best_cost: tuple[int, int] | None = None
        best_offset = 0
        for offset in range(period):
            hit = loads[offset::period]
            new_max = max(current_max, int(hit.max()) + 1)
            # The sum of squared loads grows by sum((l + 1)^2 - l^2) over the ticks hit.
            cost = (new_max, int((2 * hit + 1).sum()))
            if best_cost is None or cost < best_cost:  # strict: the smallest offset wins ties
                best_cost, best_offset = cost, offset
        loads[best_offset::period] += 1
        offsets.append(best_offset)
    return offsets


def _branch_and_bound(
    periods: Sequence[int],
    hyperperiod: int,
    incumbent: list[int],
    incumbent_max: int,
    bound: int,
    node_limit: int,
) -> tuple[list[int], int]:
    """Depth-first search for offsets whose max load is below ``incumbent_max``.

    Two symmetries shrink the tree without losing any optimum:

    * shifting every task by the same number of ticks only rotates the loads, so the first task
      can be pinned to offset 0;
    * tasks of equal period are interchangeable, so within a run of equal periods the offsets
      can be taken non-decreasing.

    A partial assignment is pruned once its max load reaches the incumbent's, since adding tasks
    never lowers a load.  The search stops at the lower bound (nothing can beat it) or after
    ``node_limit`` placements.
    """
    loads = np.zeros(hyperperiod, dtype=np.int64)
    chosen: list[int] = []
    best = list(incumbent)
    best_max = incumbent_max
    nodes = 0

    def search(depth: int, current_max: int) -> bool:
        """Extend ``chosen`` from ``depth``; return True when the search must stop."""
        nonlocal best, best_max, nodes
        if depth == len(periods):
            best, best_max = list(chosen), current_max
            return best_max <= bound
        period = periods[depth]
        if depth == 0:
            candidates = range(1)
        elif periods[depth - 1] == period:
            candidates = range(chosen[-1], period)
        else:
            candidates = range(period)
        for offset in candidates:
            if nodes >= node_limit:
                return True
            nodes += 1
            new_max = max(current_max, int(loads[offset::period].max()) + 1)
            if new_max >= best_max:
                continue
            loads[offset::period] += 1
            chosen.append(offset)
            stop = search(depth + 1, new_max)
            chosen.pop()
            loads[offset::period] -= 1
            if stop:
                return True
        return False

    search(0, 0)
    return best, best_max
