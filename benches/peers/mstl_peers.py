"""MTL peers for the progression benchmark (de Leng's thesis, Figures 3.6/3.7): reelay and mstlo.

usage: mstl_peers.py --peer {reelay,mstlo} --formula {F1,F2} --pattern {true,gap}
                     [--formulas N] [--states S] [--reelay-mode {discrete,condensing,dense}]
                     [--mstlo-semantics {EagerQualitative,DelayedQualitative}]
prints one JSON line: peer, version, formula, spec, pattern, formulas, states, median_us, p99_us,
max_us, peak_rss_kb, plus the verdict check (verdict, expected, verdict_ok, mismatches) and notes.

The workload: N independent monitors (one per formula), all fed the same S states, one every
100 ms, with one proposition p.
  pattern true: p holds at every state
  pattern gap:  p is false for 10 steps, then true for 1 (step k has p iff k % 11 == 10)
  F1 = G F[0,1000ms] p                              holds on both patterns
  F2 = G (!p -> F[0,1000ms] G[0,999ms] p)           holds on true, violated on gap
Per step, the wall time (perf_counter_ns) to feed that state to all N monitors is divided by N:
the figures are microseconds per formula-step, so they stay comparable when --states is reduced.

Peers (pin: reelay==25.0.0, mstlo-python==0.2.2):
  reelay is past-time only. The future formula's body at step i is equivalent to a past formula
  at step i+D, D the body's horizon, so the peer monitors that past formula at every step and its
  verdict at step k >= D is the body's verdict at step k-D (the outer G is the monitor running at
  every step; the first D steps, where the past formula lacks history, are not verdicts of F):
    F1: once[0:10] {p}                                                   (D = 10 steps)
    F2: (once[19:19] {p: false}) -> (once[0:10] (historically[0:9] {p})) (D = 19 steps)
  In dense mode the bounds are milliseconds (time = 100*k): once[0:1000], once[1999:1999],
  historically[0:999]. Reelay needs the parentheses: `once[0:10] historically[0:9] {p}` is a syntax
  error that reelay reports on stderr and then monitors as something else (or segfaults).
  mstlo has bounded future STL only (no unbounded G), over dense time with zero-order hold:
  the monitor evaluates the body at every sample, so the outer G is again the monitor's loop.
    F1: F[0, 1000](p > 0)       F2: !(p > 0) -> F[0, 1000](G[0, 999](p > 0))
  with p fed as 1.0 / -1.0 at timestamps 100*k (milliseconds, exact in floats).
"""
import argparse
import gc
import json
import math
import resource
import statistics
import sys
import time

THESIS_STATES = 10000
STEP_MS = 100
# Horizon of each formula's body, in steps: F[0,10] for F1, F[0,10] G[0,9] for F2.
HORIZON = {"F1": 10, "F2": 19}
EXPECTED = {("F1", "true"): True, ("F1", "gap"): True, ("F2", "true"): True, ("F2", "gap"): False}

REELAY_SPECS = {
    "discrete": {
        "F1": "once[0:10] {p}",
        "F2": "(once[19:19] {p: false}) -> (once[0:10] (historically[0:9] {p}))",
    },
    "dense": {
        "F1": "once[0:1000] {p}",
        "F2": "(once[1999:1999] {p: false}) -> (once[0:1000] (historically[0:999] {p}))",
    },
}
REELAY_SPECS["condensing"] = REELAY_SPECS["discrete"]
# Delay D of the past-time counterpart, in the peer's time unit (steps, or ms when dense).
REELAY_DELAY = {"discrete": {"F1": 10, "F2": 19}, "dense": {"F1": 1000, "F2": 1999}}
REELAY_DELAY["condensing"] = REELAY_DELAY["discrete"]

MSTLO_SPECS = {
    "F1": "F[0, 1000](p > 0)",
    "F2": "!(p > 0) -> F[0, 1000](G[0, 999](p > 0))",
}


def trace(pattern, states):
    if pattern == "true":
        return [True] * states
    return [k % 11 == 10 for k in range(states)]


def reference(formula, ps):
    """The body of the formula at each step (future-time, discrete 100 ms steps); None when the
    trace ends before the body is decided."""
    n = len(ps)
    out = []
    for i in range(n):
        if i + HORIZON[formula] >= n:
            out.append(None)
        elif formula == "F1":
            out.append(any(ps[i:i + 11]))
        else:
            out.append(ps[i] or any(all(ps[j:j + 10]) for j in range(i, i + 11)))
    return out


def value_at(changes, t):
    """Forward-filled value at time t from a sorted list of (time, value) change points."""
    lo, hi, v = 0, len(changes) - 1, None
    while lo <= hi:
        mid = (lo + hi) // 2
        if changes[mid][0] <= t:
            v = changes[mid][1]
            lo = mid + 1
        else:
            hi = mid - 1
    return v


class Reelay:
    name = "reelay"

    def __init__(self, formula, mode):
        import reelay
        from importlib.metadata import version

        self.version = version("reelay")
        self.mode = mode
        self.formula = formula
        self.spec = REELAY_SPECS[mode][formula]
        self.delay = REELAY_DELAY[mode][formula]
        self._reelay = reelay
        self.changes = []  # (time, value) of monitor 0

    def make(self):
        if self.mode == "dense":
            return self._reelay.dense_timed_monitor(pattern=self.spec)
        return self._reelay.discrete_timed_monitor(pattern=self.spec, condense=self.mode == "condensing")

    def inputs(self, ps):
        if self.mode == "dense":
            return [({"time": k * STEP_MS, "p": p},) for k, p in enumerate(ps)]
        return [({"p": p},) for p in ps]

    def record(self, k, out):
        if self.mode == "dense":  # a list of {time, value} change points
            self.changes.extend((d["time"], d["value"]) for d in out)
        elif self.mode == "condensing":  # {time, value} on a change, {} otherwise
            if out:
                self.changes.append((out["time"], out["value"]))
        else:  # {value} at every step
            self.changes.append((k, out["value"]))

    def check(self, ref, states):
        """Pointwise: the past verdict at time(i)+D must equal the future body at step i."""
        mismatches, checked, first_bad, overall = 0, 0, None, True
        unit = STEP_MS if self.mode == "dense" else 1
        last = (states - 2) * unit  # dense verdicts lag one update
        for i, r in enumerate(ref):
            t = i * unit + self.delay
            if r is None or t > last:
                continue
            v = value_at(self.changes, t)
            checked += 1
            if v is not r:
                mismatches += 1
            if v is False:
                overall = False
                if first_bad is None:
                    first_bad = t
        return overall, checked, mismatches, first_bad


class Mstlo:
    name = "mstlo"

    def __init__(self, formula, semantics):
        import mstlo_python
        from importlib.metadata import version

        self.version = version("mstlo-python")
        self.mode = semantics
        self.formula = formula
        self.spec = MSTLO_SPECS[formula]
        self._m = mstlo_python
        self._phi = mstlo_python.parse_formula(self.spec)
        self.outs = []  # outputs of monitor 0, read after the timed region
        self.delay = 0

    def make(self):
        return self._m.Monitor(self._phi, semantics=self.mode)

    def inputs(self, ps):
        return [("p", 1.0 if p else -1.0, float(k * STEP_MS)) for k, p in enumerate(ps)]

    def record(self, k, out):
        self.outs.append(out)

    def check(self, ref, states):
        verdicts = {}
        for out in self.outs:
            for t, v in out.verdicts():
                verdicts[t] = v
        mismatches, checked, first_bad = 0, 0, None
        for i, r in enumerate(ref):
            v = verdicts.get(float(i * STEP_MS))
            if r is None or v is None:
                continue
            checked += 1
            if v is not r:
                mismatches += 1
        bad = sorted(t for t, v in verdicts.items() if v is False)
        if bad:
            first_bad = bad[0]
        # The outer G: every verdict emitted, at samples and at the dense breakpoints between.
        return not bad, checked, mismatches, first_bad


def percentile(sorted_vals, q):
    return sorted_vals[max(0, math.ceil(q * len(sorted_vals)) - 1)]


def python_overhead_us(n, inputs, steps):
    """Per formula-step cost of calling a no-op Python function the same way: the floor of any
    peer driven from Python."""
    noop = [(lambda *a: None) for _ in range(n)]
    samples = []
    for args in inputs[:steps]:
        t0 = time.perf_counter_ns()
        for u in noop:
            u(*args)
        samples.append((time.perf_counter_ns() - t0) / n)
    return round(statistics.median(samples) / 1000, 4)


def run(args):
    if args.peer == "reelay":
        peer = Reelay(args.formula, args.reelay_mode)
    else:
        peer = Mstlo(args.formula, args.mstlo_semantics)
    base_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    ps = trace(args.pattern, args.states)
    inputs = peer.inputs(ps)
    monitors = [peer.make() for _ in range(args.formulas)]
    first = monitors[0].update
    rest = [m.update for m in monitors[1:]]
    n = args.formulas
    per_step = []
    gc.collect()
    gc.disable()
    wall0 = time.perf_counter()
    for k, a in enumerate(inputs):
        t0 = time.perf_counter_ns()
        out = first(*a)
        for u in rest:
            u(*a)
        dt = time.perf_counter_ns() - t0
        per_step.append(dt / n)
        peer.record(k, out)
    wall = time.perf_counter() - wall0
    gc.enable()
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    overall, checked, mismatches, first_bad = peer.check(reference(args.formula, ps), args.states)
    expected = EXPECTED[(args.formula, args.pattern)]
    s = sorted(per_step)
    res = {
        "peer": peer.name,
        "version": peer.version,
        "formula": args.formula,
        "spec": peer.spec,
        "pattern": args.pattern,
        "formulas": n,
        "states": args.states,
        "median_us": round(statistics.median(s) / 1000, 4),
        "p99_us": round(percentile(s, 0.99) / 1000, 4),
        "max_us": round(s[-1] / 1000, 4),
        "peak_rss_kb": peak_rss,
        "mode": peer.mode,
        "verdict": "holds" if overall else "violated",
        "expected": "holds" if expected else "violated",
        "verdict_ok": overall == expected and mismatches == 0,
        "points_checked": checked,
        "pointwise_mismatches": mismatches,
        "first_violation_at": first_bad,
        "time_unit": "ms" if peer.name == "mstlo" or peer.mode == "dense" else "step",
        "base_rss_kb": base_rss,
        "py_call_overhead_us": python_overhead_us(n, inputs, min(200, len(inputs))),
        "wall_s": round(wall, 2),
    }
    if peer.name == "reelay":
        res["note"] = (f"past-time counterpart; its verdict at time t+{peer.delay} is F's body at t")
    if args.states < THESIS_STATES:
        res["states_note"] = (f"states reduced from the thesis's {THESIS_STATES} to {args.states}; "
                              "per-formula-step figures stay comparable")
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer", choices=["reelay", "mstlo"], required=True)
    ap.add_argument("--formula", choices=["F1", "F2"], required=True)
    ap.add_argument("--pattern", choices=["true", "gap"], required=True)
    ap.add_argument("--formulas", type=int, default=1000)
    ap.add_argument("--states", type=int, default=THESIS_STATES)
    ap.add_argument("--reelay-mode", choices=["discrete", "condensing", "dense"], default="discrete")
    ap.add_argument("--mstlo-semantics", choices=["EagerQualitative", "DelayedQualitative"],
                    default="EagerQualitative")
    args = ap.parse_args()
    if args.formulas < 1 or args.states < 2 * HORIZON[args.formula] + 2:
        print(json.dumps({"peer": args.peer, "error": "need --formulas >= 1 and --states >= 40"}))
        return
    try:
        res = run(args)
    except (ImportError, ValueError, RuntimeError, AttributeError) as e:
        res = {"peer": args.peer, "error": f"{type(e).__name__}: {e}"}
    print(json.dumps(res))
    sys.stdout.flush()


if __name__ == "__main__":
    main()
