#!/usr/bin/env python3
"""Per-request cost of a SPARQL lookup, `dyknow` binaries side by side.

Usage: python3 benches/sparql_per_request.py BIN [BIN...]   (ROUNDS=4 by default)

Starts each binary with `serve --in-memory --model-only --specs specs/turtle/example-12.ttl`
on a free loopback port, then, round after round, sends 3,200 lookups by label from one
connection to each in turn (`http.client`, POST application/sparql-query) and prints each
round's median latency after 200 of warm-up. Interleaving the binaries spreads the machine's
drift over all of them. SPLIT=1 sends each request's head and body in two writes. Every server it starts is killed at the end.
"""
import http.client, subprocess, sys, time, statistics, os, socket
bins = sys.argv[1:]
Q = b'PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#> SELECT ?t WHERE { ?t rdfs:label "tid4" }'
HEADERS = {"Content-Type": "application/sparql-query", "Accept": "application/sparql-results+json"}
# SPLIT=1: the head and the body in two writes (two segments), as some clients send them
# (ureq, the Rust benches' client); by default in one, as http.client does.
SPLIT = os.environ.get("SPLIT") == "1"
def free_port():
    s = socket.socket(); s.bind(("127.0.0.1", 0)); p = s.getsockname()[1]; s.close(); return p
servers = []
for b in bins:
    port = free_port()
    p = subprocess.Popen([b, "serve", "--in-memory", "--model-only", "--bind", f"127.0.0.1:{port}",
                          "--specs", os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "specs", "turtle", "example-12.ttl")],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=dict(os.environ, RUST_LOG="error"))
    servers.append((b, port, p))
try:
    for b, port, p in servers:
        for _ in range(600):
            try:
                c = http.client.HTTPConnection("127.0.0.1", port); c.request("GET", "/health"); c.getresponse().read(); break
            except OSError:
                time.sleep(0.05)
    res = {b: [] for b in bins}
    for rnd in range(int(os.environ.get("ROUNDS", "4"))):
        for b, port, p in servers:
            c = http.client.HTTPConnection("127.0.0.1", port)
            lat = []
            for i in range(3200):
                t = time.perf_counter()
                if SPLIT:
                    c.putrequest("POST", "/sparql")
                    for k, v in HEADERS.items():
                        c.putheader(k, v)
                    c.putheader("Content-Length", str(len(Q)))
                    c.endheaders()
                    c.send(Q)
                else:
                    c.request("POST", "/sparql", body=Q, headers=HEADERS)
                r = c.getresponse(); body = r.read()
                lat.append(time.perf_counter() - t)
                assert r.status == 200, body
            res[b].append(statistics.median(lat[200:]) * 1e3)
    for b in bins:
        print(b, " ".join(f"{x:.4f}" for x in res[b]), "ms")
finally:
    for b, port, p in servers:
        p.kill(); p.wait()
