"""One plan search in a process of its own, for :func:`~sb3_pm.planning.planner.plan_both_ways`.

``python -m sb3_pm.planning.search_worker`` reads the positional and keyword arguments of
:func:`~sb3_pm.planning.planner.plan_patrol` from standard input and writes the plan to standard
output, both pickled. Only :func:`~sb3_pm.planning.planner.plan_both_ways` starts it, with
arguments it pickled itself; no file is read. A worker started this way imports nothing of its
caller's script, as a ``multiprocessing`` spawn would.
"""

from __future__ import annotations

import pickle
import sys


def main() -> None:
    from sb3_pm.planning.planner import plan_patrol

    args, kwargs = pickle.load(sys.stdin.buffer)
    pickle.dump(plan_patrol(*args, **kwargs), sys.stdout.buffer)


if __name__ == "__main__":
    main()
