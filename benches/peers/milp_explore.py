"""An exact reference for EXPLORE (issue 18), independent of it: the configuration problem as a
mixed-integer linear programme, solved by HiGHS (PyPI `highspy`). Reads one instance (the JSON
lifecycle/benches/explore.rs writes from the environment and the candidate table, as the CP-SAT
reference reads it) on stdin, or from the file given, and prints one JSON line: the cheapest
configuration found, HiGHS's proven lower bound, its status and time.

The problem is cpsat_explore.py's (seed Ch. 4.3 with DyKnow's rules, docs/engine.md): a set of
transformations, one node each; every input of a chosen one read from a chosen provider; every
target from one chosen (transformation, out port) or left unsatisfied (the pragmatic
relaxation, at a weight above every real cost); one out port feeds one channel, targets on one
channel read from one port; d further CUs of a chosen transformation let each of its out ports
feed 1 + d channels (an unused existing CU, else a spawn).

What differs from the CP-SAT model is the formulation, which is what makes the bound useful:
- x[t] binary: t is chosen (protected CUs' transformations always, their upkeep the
  instance's constant);
- for each target k and each transformation t that may take part in feeding it (the backward
  closure of the candidate table from its providers), u[k][t] in [0, 1]: t is in k's feeding
  graph; u[k][t] <= x[t]; each input of t has providers in k's graph summing to at least
  u[k][t]; the target's chosen port's transformation has u = 1. This is the multi-commodity
  "reach" formulation of benches/peers/lp_explore.py, whose LP relaxation is far tighter than
  the compact one (x[t] <= the sum of x over each input's providers), so branch and bound
  closes the gap instead of enumerating it;
- the u need not be integral: with x integral, the transformations where u > 0 feed target k
  from sources (each input has a provider among them), because the candidate table is
  acyclic. A cyclic table would let a cycle feed itself: the script refuses it (status
  "cyclic"), where the CP-SAT model's integer levels apply.

Costs stay floating point; the reported cost is recomputed from the chosen set, and the bound
is HiGHS's dual bound (less the unsatisfied weight it implies).
"""

import ctypes
import json
import os
import sys
import time

import highspy

from explore_instance import answer, further_kinds
from explore_instance import reach as reach_of


def quiet_highs():
    """A HiGHS instance that logs nothing: its constructor prints a banner on standard output,
    which is kept for the one JSON line, so the banner goes to standard error."""
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    try:
        h = highspy.Highs()
        h.setOptionValue("output_flag", False)
        ctypes.CDLL(None).fflush(None)
    finally:
        os.dup2(saved, 1)
        os.close(saved)
    return h


def acyclic(tfs):
    """Whether the candidate table (provider -> consumer) has no cycle (Kahn)."""
    n = len(tfs)
    consumers = [set() for _ in range(n)]
    waiting = [0] * n
    for t, tf in enumerate(tfs):
        ps = {p for ins in tf["inputs"] for p, _port in ins}
        waiting[t] = len(ps)
        for p in ps:
            consumers[p].add(t)
    ready = [t for t in range(n) if waiting[t] == 0]
    seen = 0
    while ready:
        t = ready.pop()
        seen += 1
        for c in consumers[t]:
            waiting[c] -= 1
            if waiting[c] == 0:
                ready.append(c)
    return seen == n


def solve(instance, seconds, threads):
    tfs = instance["transformations"]
    targets = instance["targets"]
    n = len(tfs)
    if not acyclic(tfs):
        return {"status": "cyclic", "seconds": 0.0}
    h = quiet_highs()
    h.setOptionValue("time_limit", float(seconds))
    h.setOptionValue("threads", int(threads))
    h.setOptionValue("mip_rel_gap", 0.0)
    h.setOptionValue("mip_abs_gap", 1e-6)
    inf = highspy.kHighsInf
    # Transformations whose inputs can never all be fed from sources are in no configuration.
    feedable = [False] * n
    changed = True
    while changed:
        changed = False
        for t, tf in enumerate(tfs):
            if not feedable[t] and all(
                any(feedable[p] and p != t for p, _port in ins) for ins in tf["inputs"]
            ):
                feedable[t] = True
                changed = True
    costs = [0.0 if tf["protected"] else tf["cost"] for tf in tfs]
    x = []
    for t, tf in enumerate(tfs):
        lo = 1.0 if tf["protected"] else 0.0
        hi = 1.0 if feedable[t] or tf["protected"] else 0.0
        x.append(h.addVariable(lb=lo, ub=hi, obj=costs[t], type=highspy.HighsVarType.kInteger))
    # Every input of a chosen transformation is read from a chosen provider (the compact rows;
    # implied by the reach rows for the transformations targets need, stated for the others,
    # protected ones included).
    for t, tf in enumerate(tfs):
        for ins in tf["inputs"]:
            ps = sorted({p for p, _port in ins if p != t})
            h.addConstr(sum(x[p] for p in ps) - x[t] >= 0 if ps else x[t] <= 0)
    channels = sorted({q["channel"] for q in targets})
    big = sum(costs) + len(channels) * sum(
        max(tf.get("spawn", tf["cost"]), tf["cost"]) for tf in tfs
    ) + 1.0
    relax = instance["relax"]
    unsat, fvars = [], []
    feeds = {}  # (tid, port) -> {channel: [f]}
    for k, target in enumerate(targets):
        u_k = h.addVariable(lb=0.0, ub=1.0 if relax else 0.0, obj=big,
                            type=highspy.HighsVarType.kInteger)
        unsat.append(u_k)
        ports = sorted({(p, port) for p, port in target["providers"] if feedable[p]})
        # The reach of target k: what may take part in feeding it.
        reach = reach_of(tfs, [p for p, _port in ports], lambda p: feedable[p])
        u = {t: h.addVariable(lb=0.0, ub=1.0) for t in sorted(reach)}
        for t in sorted(reach):
            h.addConstr(u[t] - x[t] <= 0)
            for ins in tfs[t]["inputs"]:
                ps = sorted({p for p, _port in ins if p != t and p in reach})
                h.addConstr(sum(u[p] for p in ps) - u[t] >= 0 if ps else u[t] <= 0)
        fs = {}
        for key in ports:
            f = h.addVariable(lb=0.0, ub=1.0, type=highspy.HighsVarType.kInteger)
            fs[key] = f
            feeds.setdefault(key, {}).setdefault(target["channel"], []).append(f)
        for p in {p for p, _port in ports}:
            h.addConstr(sum(f for (q, _port), f in fs.items() if q == p) - u[p] <= 0)
        h.addConstr(sum(fs.values()) + u_k == 1)
        fvars.append(fs)
    # Further CUs of t: free (other protected CUs), kept (other existing CUs), spawned.
    further = {}
    for t in sorted({p for p, _port in feeds}):
        tf = tfs[t]
        free_n, kept_n = further_kinds(tf)
        m = len(channels)
        integer = highspy.HighsVarType.kInteger
        free = h.addVariable(lb=0, ub=min(free_n, m), obj=0.0, type=integer)
        kept = h.addVariable(lb=0, ub=min(kept_n, m), obj=tf.get("keep", tf["cost"]), type=integer)
        spawned = h.addVariable(lb=0, ub=m, obj=tf.get("spawn", tf["cost"]), type=integer)
        h.addConstr(free + kept + spawned - m * x[t] <= 0)
        further[t] = (free, kept, spawned)
    # One out port feeds one channel per CU of its transformation.
    for (t, _port), by_channel in feeds.items():
        used = []
        for _channel, fs in sorted(by_channel.items()):
            if len(fs) == 1:
                used.append(fs[0])
                continue
            g = h.addVariable(lb=0.0, ub=1.0, type=highspy.HighsVarType.kInteger)
            for f in fs:
                h.addConstr(f - g <= 0)
            used.append(g)
        free, kept, spawned = further[t]
        h.addConstr(sum(used) - x[t] - free - kept - spawned <= 0)
    # Targets on one channel, when fed, read from the same port.
    for k1, t1 in enumerate(targets):
        for k2, t2 in enumerate(targets):
            if k1 != k2 and t1["channel"] == t2["channel"]:
                for key, f1 in fvars[k1].items():
                    f2 = fvars[k2].get(key)
                    h.addConstr(f1 - unsat[k2] <= 0 if f2 is None else f1 - f2 - unsat[k2] <= 0)
    start = time.perf_counter()
    h.run()
    elapsed = time.perf_counter() - start
    status = h.getModelStatus()
    info = h.getInfo()
    name = h.modelStatusToString(status).lower()
    if info.primal_solution_status < 2:  # no feasible solution
        return {"status": name, "seconds": elapsed}
    value = h.getSolution().col_value
    chosen = [t for t in range(n) if value[x[t].index] > 0.5]
    unsatisfied = sum(1 for u_k in unsat if value[u_k.index] > 0.5)
    cost = sum(costs[t] for t in chosen) + instance.get("constant", 0.0)
    runs = 0
    for t, (free, kept, spawned) in further.items():
        k_n = round(value[kept.index])
        s_n = round(value[spawned.index])
        runs += round(value[free.index]) + k_n + s_n
        cost += k_n * tfs[t].get("keep", tfs[t]["cost"]) + s_n * tfs[t].get("spawn", tfs[t]["cost"])
    dual = info.mip_dual_bound
    bound_unsat = int(dual // big) if dual < inf else unsatisfied
    bound = dual - bound_unsat * big + instance.get("constant", 0.0)
    return answer(name, cost, unsatisfied, bound, bound_unsat, len(chosen), runs, elapsed,
                  nodes=info.mip_node_count)


def main():
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 60.0
    threads = int(sys.argv[2]) if len(sys.argv) > 2 else 2
    source = open(sys.argv[3]) if len(sys.argv) > 3 else sys.stdin
    print(json.dumps(solve(json.load(source), seconds, threads)))


if __name__ == "__main__":
    main()
