#!/usr/bin/env python3
"""EXPLORE's any-time costs, bench binaries side by side, paired over fresh generated instances.

Usage: python3 benches/explore_paired.py BIN [BIN...]
       (SEEDS=8-39 RUNS=2 AT=100 by default)

Each BIN is a copy of the engine bench binary (`cargo bench --locked --workspace --bench
explore --no-run` prints its path; copy it before building the next variant, since Cargo
writes every build to the same path). Run after run, each binary in turn runs the seeds table
(`--bench`, from `lifecycle/` as `cargo bench` does) with `EXPLORE_SEEDS=$SEEDS
EXPLORE_AT=$AT,$AT,$AT EXPLORE_CAP_SECONDS=0`: the 500 x 20, 1,000 x 30 and 2,000 x 50
instances of every seed, three searches of $AT ms each.

Why paired, and why fresh seeds: a search of 100 ms is nearly deterministic (the main search
is, and the probes' rounds are seeded), so the three columns and the repeated runs of the
bench's eight seeds are not independent samples: a change of the search moves which of the
24 instances land in a poor local optimum, and a count of misses over those 24 says little
about whether it helps (docs/benchmarks.md, "Basins at 100 ms"). Here the reference of each
instance is the cheapest cost any binary found in any run (an optimistic reference: the true
optimum may be lower), and each binary after the first is compared with the first instance by
instance: the mean of log(cost / first binary's cost) over instances, with its standard
error, and the instances where it is cheaper or dearer. Seeds 0-7 are the bench's own; the
default 8-39 keeps a change from being tuned to them.
"""
import collections
import math
import os
import re
import subprocess
import sys

ROW = re.compile(r"^\| (\d+) \| (\d+) × (\d+) \|")


def run(binary, seeds, at):
    """The costs of one seeds table: {(seed, size): [cost at each mark]}."""
    env = dict(
        os.environ,
        EXPLORE_SEEDS=seeds,
        EXPLORE_AT=f"{at},{at},{at}",
        EXPLORE_CAP_SECONDS="0",
    )
    here = os.path.dirname(os.path.abspath(__file__))
    out = subprocess.run(
        [binary, "--bench"],
        cwd=os.path.join(here, "..", "lifecycle"),
        env=env,
        check=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    ).stdout
    costs = {}
    for line in out.splitlines():
        m = ROW.match(line)
        if not m:
            continue
        cells = line.split("|")[4:7]
        values = []
        for cell in cells:
            c = re.match(r"\s*([\d.]+)", cell)
            # A cell with unsatisfied targets counts as missing everything.
            values.append(float(c.group(1)) if c and "unsatisfied" not in cell else math.inf)
        costs[(int(m.group(1)), m.group(2))] = values
    if not costs:
        sys.exit(f"{binary} printed no seeds table")
    return costs


def mean(xs):
    return sum(xs) / len(xs)


def main():
    binaries = sys.argv[1:]
    if not binaries:
        sys.exit(__doc__)
    seeds = os.environ.get("SEEDS", "8-39")
    runs = int(os.environ.get("RUNS", "2"))
    at = int(os.environ.get("AT", "100"))
    samples = {b: collections.defaultdict(list) for b in binaries}
    for r in range(runs):
        for b in binaries:
            for key, values in run(b, seeds, at).items():
                samples[b][key].extend(values)
            print(f"run {r + 1}/{runs}: {b} done", file=sys.stderr)
    keys = sorted(set.intersection(*(set(s) for s in samples.values())))
    best = {k: min(min(samples[b][k]) for b in binaries) for k in keys}
    first = binaries[0]
    print(f"# EXPLORE at {at} ms, seeds {seeds}, {runs} runs x 3 searches per binary and instance")
    print("# reference: the cheapest cost any binary found for the instance in these runs\n")
    print("| binary | size | instances | mean gap to the reference | instances more than 1 % above it (mean over samples) |")
    print("| --- | --- | --- | --- | --- |")
    for b in binaries:
        for size in sorted({k[1] for k in keys}, key=int):
            ks = [k for k in keys if k[1] == size]
            gap = mean([mean(samples[b][k]) / best[k] - 1 for k in ks])
            miss = sum(mean([float(c > 1.01 * best[k]) for c in samples[b][k]]) for k in ks)
            print(f"| {b} | {size} | {len(ks)} | {100 * gap:.3f} % | {miss:.2f} |")
    print()
    for b in binaries[1:]:
        d = [math.log(mean(samples[b][k]) / mean(samples[first][k])) for k in keys]
        mu = mean(d)
        se = (sum((x - mu) ** 2 for x in d) / (len(d) - 1)) ** 0.5 / len(d) ** 0.5
        cheaper = sum(x < -1e-9 for x in d)
        dearer = sum(x > 1e-9 for x in d)
        print(
            f"{b} against {first}: mean cost {100 * mu:+.3f} % (standard error {100 * se:.3f} %), "
            f"cheaper on {cheaper}, dearer on {dearer} of {len(d)} instances"
        )


if __name__ == "__main__":
    main()
