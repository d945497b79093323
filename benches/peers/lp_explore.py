"""A linear-programming lower bound for EXPLORE's configuration problem (issue 18): how far
below the optimum a bound from the problem's usual strong relaxation lies. Reads one instance
(the JSON lifecycle/benches/explore.rs writes with EXPLORE_INSTANCES=DIR; the CP-SAT reference
reads the same) from the file given, or stdin, and prints one JSON line: the bound and GLOP's
time.

The relaxation (a multi-commodity "reach" formulation, solved as an LP with OR-Tools' GLOP):
- x[t] in [0, 1]: transformation t is chosen, at its node cost (protected ones: 1, their
  upkeep the instance's constant);
- for each target k and each transformation t that may feed it, directly or through inputs,
  u[k][t] in [0, 1]: t is in k's feeding graph; u[k][t] <= x[t];
- the target is fed: the sum of u[k][p] over its providers p is at least 1;
- each input of t in k's graph is fed: the sum of u[k][p] over the input's providers is at
  least u[k][t].
Minimise the chosen transformations' cost. Every configuration that feeds every target gives a
feasible point of this LP (u[k][t] = 1 for the transformations of k's graph), so its optimum
is a lower bound on every such configuration. It drops what only makes configurations dearer
(acyclicity, one channel per out port, further CUs), so it stays a bound. Leaving a target
unsatisfied (the pragmatic relaxation) is not modelled: the bound holds for configurations
that feed every target, which the benchmark's layered instances' optima all do.
"""

import json
import sys

from ortools.linear_solver import pywraplp

from explore_instance import reach as reach_of


def bound(instance):
    tfs = instance["transformations"]
    solver = pywraplp.Solver.CreateSolver("GLOP")
    x = [solver.NumVar(0, 1, f"x{t}") for t in range(len(tfs))]
    for t, tf in enumerate(tfs):
        if tf["protected"]:
            solver.Add(x[t] == 1)
    for k, target in enumerate(instance["targets"]):
        providers = sorted({p for p, _port in target["providers"]})
        reach = reach_of(tfs, providers)
        u = {t: solver.NumVar(0, 1, f"u{k}_{t}") for t in reach}
        for t in reach:
            solver.Add(u[t] <= x[t])
            for ps in tfs[t]["inputs"]:
                solver.Add(sum(u[p] for p in sorted({p for p, _port in ps})) >= u[t])
        solver.Add(sum(u[p] for p in providers) >= 1)
    # Protected CUs' upkeep is the instance's constant (as in cpsat_explore.py).
    solver.Minimize(
        sum(tf["cost"] * x[t] for t, tf in enumerate(tfs) if not tf["protected"])
    )
    status = solver.Solve()
    if status != pywraplp.Solver.OPTIMAL:
        return {"status": "infeasible" if status == pywraplp.Solver.INFEASIBLE else "failed"}
    return {
        "status": "optimal",
        "bound": solver.Objective().Value() + instance.get("constant", 0.0),
        "variables": solver.NumVariables(),
        "seconds": solver.wall_time() / 1000.0,
    }


if __name__ == "__main__":
    source = open(sys.argv[1]) if len(sys.argv) > 1 else sys.stdin
    print(json.dumps(bound(json.load(source))))
