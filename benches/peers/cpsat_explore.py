"""The independent reference for EXPLORE (issue 18): the same configuration problem as a CP-SAT
model, solved by OR-Tools. Reads one instance (JSON, written by lifecycle/benches/explore.rs
from the environment and the candidate table, not from EXPLORE's own structures) on stdin and
prints one JSON line: the optimum found, CP-SAT's proven lower bound, its status and time.

The problem (seed Ch. 4.3, with DyKnow's rules, docs/engine.md):
- choose a set of transformations, one node each (an existing CU kept: horizon x upkeep; none
  existing: a spawn, labour + horizon x upkeep; a protected CU: always chosen, its upkeep a
  constant);
- every input of a chosen transformation reads from one chosen provider (the candidate table),
  and the wiring is acyclic (integer levels);
- every target reads from one chosen (transformation, out port), or is left unsatisfied (the
  pragmatic relaxation) at a cost above every real cost (lexicographic: a big weight);
- one out port feeds one channel; targets on one channel, when fed, read from the same port;
- a chosen transformation may run more than once: d further CUs of it let each of its out
  ports feed up to 1 + d channels. A further CU is one of its existing CUs the first does not
  use (another protected one: free; any other: horizon x upkeep), else a spawn (labour +
  horizon x upkeep). Further CUs read what the first reads, so they add no wiring.

Costs are scaled to integers (x 1e6, rounded); the reported cost is recomputed in floating
point from the chosen set, and the bound is CP-SAT's scaled bound minus the rounding slack.
"""

import json
import sys
import time

from ortools.sat.python import cp_model

from explore_instance import answer, further_kinds

SCALE = 1_000_000


def solve(instance, seconds, workers):
    model = cp_model.CpModel()
    tids = instance["transformations"]
    n = len(tids)
    x = [model.NewBoolVar(f"x{t}") for t in range(n)]
    level = [model.NewIntVar(0, n, f"l{t}") for t in range(n)]
    for t, tf in enumerate(tids):
        if tf["protected"]:
            model.Add(x[t] == 1)
        for i, providers in enumerate(tf["inputs"]):
            ps = sorted({p for p, _port in providers})
            if not ps:
                model.Add(x[t] == 0)
                continue
            edges = []
            for p in ps:
                e = model.NewBoolVar(f"e{t}_{i}_{p}")
                model.AddImplication(e, x[p])
                if p == t:
                    model.Add(e == 0)
                else:
                    model.Add(level[t] >= level[p] + 1).OnlyEnforceIf(e)
                edges.append(e)
            model.Add(sum(edges) == x[t])
    targets = instance["targets"]
    relax = instance["relax"]
    unsat = []
    feeds = {}  # (tid, port) -> {channel: [f vars]}
    fvars = []  # per target: {(tid, port): var}
    for q, target in enumerate(targets):
        u = model.NewBoolVar(f"u{q}")
        if not relax:
            model.Add(u == 0)
        unsat.append(u)
        fs = {}
        for p, port in {(p, port) for p, port in target["providers"]}:
            f = model.NewBoolVar(f"f{q}_{p}_{port}")
            model.AddImplication(f, x[p])
            fs[(p, port)] = f
            feeds.setdefault((p, port), {}).setdefault(target["channel"], []).append(f)
        model.Add(sum(fs.values()) + u == 1)
        fvars.append(fs)
    # Further CUs: d[t] = free + kept + spawned (the cheapest kinds fill first).
    further = {}
    extra_cost = []
    channels = len({t["channel"] for t in targets})
    for t in {p for p, _port in feeds}:
        tf = tids[t]
        free_n, kept_n = further_kinds(tf)
        free = model.NewIntVar(0, min(free_n, channels), f"free{t}")
        kept = model.NewIntVar(0, min(kept_n, channels), f"kept{t}")
        spawned = model.NewIntVar(0, channels, f"spawned{t}")
        d = model.NewIntVar(0, channels, f"d{t}")
        model.Add(d == free + kept + spawned)
        model.Add(d == 0).OnlyEnforceIf(x[t].Not())
        further[t] = (d, kept, spawned)
        extra_cost.append(round(tf.get("keep", tf["cost"]) * SCALE) * kept)
        extra_cost.append(round(tf.get("spawn", tf["cost"]) * SCALE) * spawned)
    # One out port feeds one channel per CU.
    for key, by_channel in feeds.items():
        used = []
        for channel, fs in by_channel.items():
            g = model.NewBoolVar(f"g{key}_{channel}")
            for f in fs:
                model.AddImplication(f, g)
            used.append(g)
        model.Add(sum(used) <= 1 + further[key[0]][0])
    # Targets on one channel, when fed, read from the same port.
    for q1, t1 in enumerate(targets):
        for q2, t2 in enumerate(targets):
            if q1 != q2 and t1["channel"] == t2["channel"]:
                for key, f1 in fvars[q1].items():
                    f2 = fvars[q2].get(key)
                    if f2 is None:
                        model.Add(f1 <= unsat[q2])
                    else:
                        model.Add(f1 <= f2 + unsat[q2])
    costs = [0 if tf["protected"] else round(tf["cost"] * SCALE) for tf in tids]
    big = sum(costs) + channels * sum(
        round(max(tf.get("spawn", tf["cost"]), tf["cost"]) * SCALE) for tf in tids
    ) + 1
    model.Minimize(
        big * sum(unsat) + sum(c * v for c, v in zip(costs, x)) + sum(extra_cost)
    )
    solver = cp_model.CpSolver()
    solver.parameters.max_time_in_seconds = seconds
    solver.parameters.num_workers = workers
    start = time.perf_counter()
    status = solver.Solve(model)
    elapsed = time.perf_counter() - start
    constant = instance["constant"]
    if status not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
        return {"status": solver.StatusName(status), "seconds": elapsed}
    chosen = [t for t in range(n) if solver.Value(x[t])]
    unsatisfied = sum(solver.Value(u) for u in unsat)
    cost = sum(0.0 if tids[t]["protected"] else tids[t]["cost"] for t in chosen) + constant
    runs = 0
    for t, (d, kept, spawned) in further.items():
        runs += solver.Value(d)
        cost += solver.Value(kept) * tids[t].get("keep", tids[t]["cost"])
        cost += solver.Value(spawned) * tids[t].get("spawn", tids[t]["cost"])
    # The bound, in the same units: the scaled bound less the big weight of the unsatisfied
    # targets it implies, less the rounding slack of every term.
    scaled_bound = solver.BestObjectiveBound()
    bound_unsat = int(scaled_bound // big)
    slack = 0.5 * (n + 2 * len(further) * channels) / SCALE
    bound = (scaled_bound - bound_unsat * big) / SCALE - slack + constant
    return answer(solver.StatusName(status), cost, unsatisfied, bound, bound_unsat, len(chosen),
                  runs, elapsed)


def main():
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 60.0
    workers = int(sys.argv[2]) if len(sys.argv) > 2 else 2
    instance = json.load(sys.stdin)
    print(json.dumps(solve(instance, seconds, workers)))


if __name__ == "__main__":
    main()
