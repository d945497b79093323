"""RCC-8 algebraic closure peer for the rcc8 crate's closure benchmark: PyRCC8 (pure Python).

usage: rcc8_peers.py FILE [--repeat K] [--pc {PC,PCw,PCew}]
prints one JSON line: peer, version, instances, mean_us, median_us, consistent, per_instance_us,
per_instance_consistent (then function, repeat, empty_input).

FILE is in GQR's CSP format, read as the rcc8 crate's gqr.rs reads it: one or more instances,
each a header `N  # comment` (N the highest variable index), lines `i j ( R1 R2 ... )` with the
names DC EC PO EQ TPP NTPP TPPI NTPPI (also TPPi/NTPPi and `TPP ^-1`), and `.` (optional at the
end of the file); `#` starts a comment; unlisted pairs are universal; `i j` and `j i` are
intersected (after converting one); `i i` is intersected with EQ.

Peer (pin: pyrcc8==1.2.2, installed by install_pyrcc8.py: PyPI's files for it are bare Python 2
folders, so that script ports them with lib2to3 and installs them as the package `pyrcc8`).
Each instance is built untimed into PyRCC8's own representation: a tuple of array('B') rows over
its bit codes (pyrcc8.bitcoding, names through pyrcc8.helpfuncs.translateR, converse through
pyrcc8.inverse.inv), the diagonal EQ, as its rcc8.py/parsecsp.py build it. Only the closure call
is timed (time.perf_counter_ns, gc disabled): by default pyrcc8.pc.PC(matrix), van Beek's
queue-based path consistency (its `--pcheuristic none`); PCw / PCew are the same closure with a
priority queue on van Beek's / exact weights (PCw is rcc8.py's default inside its search). It
refines the matrix in place and returns False as soon as a relation becomes empty, else True
(the network is then algebraically closed): that is per_instance_consistent. With --repeat K each
instance is closed K times, each on a fresh copy (copied untimed), and its figure is the median.
An instance whose input already holds an empty relation is inconsistent without a call (PC would
index its tables with -1): it counts with 0 us and in empty_input.
"""
import argparse
import gc
import json
import statistics
import sys
import time
from array import array
from importlib.metadata import version

try:
    from pyrcc8.bitcoding import DALL, EQ
    from pyrcc8.helpfuncs import translateR
    from pyrcc8.inverse import inv
    from pyrcc8.pc import PC
    from pyrcc8.pcew import PCew
    from pyrcc8.pcw import PCw
except ImportError:
    sys.exit("pyrcc8 is not installed: run benches/peers/install_pyrcc8.py with this python")

FUNCTIONS = {"PC": ("pyrcc8.pc.PC", PC), "PCw": ("pyrcc8.pcw.PCw", PCw), "PCew": ("pyrcc8.pcew.PCew", PCew)}
ALIASES = {"TPPi": "TPPI", "NTPPi": "NTPPI", "TPP^-1": "TPPI", "NTPP^-1": "NTPPI"}


def code(name, where):
    b = translateR(ALIASES.get(name, name))
    if b is None:
        sys.exit(f"{where}: '{name}' is not an RCC-8 relation")
    return b


def parse(path):
    """Yields one matrix per instance: PyRCC8's tuple of array('B') rows."""
    matrix = None
    with open(path) as f:
        for lineno, raw in enumerate(f, 1):
            line = raw.split("#", 1)[0].strip()
            where = f"{path}:{lineno}"
            if not line:
                continue
            if line == ".":
                if matrix is None:
                    sys.exit(f"{where}: '.' before an instance's header")
                yield matrix
                matrix = None
                continue
            if matrix is None:
                n = int(line) + 1
                matrix = tuple(array("B", [DALL if i != j else EQ for i in range(n)]) for j in range(n))
                continue
            head, _, rest = line.partition("(")
            body, close, tail = rest.rpartition(")")
            if not close or tail.strip():
                sys.exit(f"{where}: expected 'i j ( R ... )'")
            i, j = (int(v) for v in head.split())
            names = body.split()
            r = 0
            k = 0
            while k < len(names):
                name = names[k]
                if k + 1 < len(names) and names[k + 1] == "^-1":
                    name += "^-1"
                    k += 1
                r |= code(name, where)
                k += 1
            if i == j:
                matrix[i][i] &= r
            else:
                # inv is indexed by code - 1; the empty relation (0) is its own converse
                matrix[i][j] &= r
                matrix[j][i] = inv[matrix[i][j] - 1] if matrix[i][j] else 0
    if matrix is not None:
        yield matrix


def has_empty(matrix):
    return any(0 in row for row in matrix)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("file")
    ap.add_argument("--repeat", type=int, default=1, metavar="K")
    ap.add_argument("--pc", choices=sorted(FUNCTIONS), default="PC")
    args = ap.parse_args()
    if args.repeat < 1:
        ap.error("--repeat must be at least 1")
    fname, closure = FUNCTIONS[args.pc]

    per_us, per_ok = [], []
    empty_input = 0
    for template in parse(args.file):
        if has_empty(template):
            empty_input += 1
            per_us.append(0.0)
            per_ok.append(False)
            continue
        samples, verdicts = [], set()
        for _ in range(args.repeat):
            m = tuple(array("B", row) for row in template)
            gc.collect()
            gc.disable()
            t0 = time.perf_counter_ns()
            ok = closure(m)
            dt = time.perf_counter_ns() - t0
            gc.enable()
            samples.append(dt / 1000.0)
            verdicts.add(bool(ok))
        if len(verdicts) != 1:
            sys.exit("the peer's verdict changed between repeats")
        per_us.append(statistics.median(samples))
        per_ok.append(verdicts.pop())

    print(json.dumps({
        "peer": "pyrcc8",
        "version": version("pyrcc8"),
        "instances": len(per_us),
        "mean_us": statistics.fmean(per_us) if per_us else None,
        "median_us": statistics.median(per_us) if per_us else None,
        "consistent": sum(per_ok),
        "per_instance_us": per_us,
        "per_instance_consistent": per_ok,
        "function": fname,
        "repeat": args.repeat,
        "empty_input": empty_input,
    }))


if __name__ == "__main__":
    main()
