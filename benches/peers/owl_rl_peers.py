"""Full OWL 2 RL materialisation by the peers, timed: `owlrl` (RDFLib) and `reasonable`.

usage: owl_rl_peers.py owlrl|reasonable FILE.nt [TIMEOUT_S]
prints: seconds triples_after   (reasoning time only, parsing excluded)
"""
import sys
import time


def main():
    which, path = sys.argv[1], sys.argv[2]
    if which == "owlrl":
        import owlrl
        import rdflib

        g = rdflib.Graph()
        g.parse(path, format="nt")
        start = time.perf_counter()
        owlrl.DeductiveClosure(owlrl.OWLRL_Semantics).expand(g)
        elapsed = time.perf_counter() - start
        print(f"{elapsed:.6f} {len(g)}")
    elif which == "reasonable":
        import reasonable

        r = reasonable.PyReasoner()
        r.load_file(path)
        start = time.perf_counter()
        triples = r.reason()
        elapsed = time.perf_counter() - start
        print(f"{elapsed:.6f} {len(triples)}")
    else:
        raise SystemExit(f"unknown peer {which}")


if __name__ == "__main__":
    main()
