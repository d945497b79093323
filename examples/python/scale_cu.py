#!/usr/bin/env python3
"""A DyKnow process CU in Python (PyPI `eclipse-zenoh`): multiplies numeric samples.

It speaks the CU protocol of docs/executors.md ("In any language") with nothing but a Zenoh binding:
read the environment the executor sets, declare the control queryable, then the liveliness
token, and answer bind-in / bind-out / statistics / stop until told to stop, until the
executor (its parent process) dies, or until it crashes (exit status 1).

Spec:  dkros:hasType "process" ; dkros:hasSource "python3 /path/to/scale_cu.py" ;
       dkros:hasParam [ dyknow:hasName "factor" ; dyknow:hasValue 3 ] .
"""

import json
import os
import sys
import threading
import time

import zenoh

env = os.environ
NAME = env["DYKNOW_CU"]
NS = env.get("DYKNOW_NAMESPACE", "dyknow")
CONNECT = [e for e in env.get("DYKNOW_CONNECT", "").split(",") if e]
EXECUTOR = env.get("DYKNOW_EXECUTOR")
INPUTS = [p for p in env.get("DYKNOW_INPUTS", "").split(",") if p]
OUTPUTS = [p for p in env.get("DYKNOW_OUTPUTS", "").split(",") if p]
PARAMS = json.loads(env.get("DYKNOW_PARAMS") or "{}")
FACTOR = PARAMS.get("factor", 2)
CONTROL = f"{NS}/@dyknow"

started = time.monotonic()
lock = threading.Lock()
subscribers = {}  # in port -> (channel, subscriber)
publishers = {}  # out port -> (channel, publisher)
stats = {p: {"messages": 0, "bytes": 0, "last_t": None} for p in INPUTS + OUTPUTS}
reconfigurations = 0
done = threading.Event()
status = {"code": 0}


def on_sample(port):
    def callback(sample):
        payload = sample.payload.to_bytes()
        try:
            message = json.loads(payload)
            t, value = int(message["t"]), message["value"]
        except (ValueError, KeyError, TypeError):
            return  # not a DyKnow sample: dropped
        with lock:
            s = stats[port]
            s["messages"] += 1
            s["bytes"] += len(payload)
            s["last_t"] = t
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                return
            out = json.dumps({"t": t, "value": value * FACTOR}).encode()
            for out_port, (_, publisher) in publishers.items():
                publisher.put(out)
                o = stats[out_port]
                o["messages"] += 1
                o["bytes"] += len(out)
                o["last_t"] = t

    return callback


def control(query):
    global reconfigurations
    try:
        request = json.loads(query.payload.to_bytes()) if query.payload else None
        op = request["op"]
    except (ValueError, KeyError, TypeError) as e:
        query.reply(query.key_expr, json.dumps({"ok": False, "error": f"not a request: {e}"}))
        return
    reply = {"ok": True}
    if op in ("bind-in", "bind-out"):
        port, key = request["port"], request.get("key")
        ports, table = (INPUTS, subscribers) if op == "bind-in" else (OUTPUTS, publishers)
        if port not in ports:
            reply = {"ok": False, "error": f"{NAME} has no {op[5:]} port {port!r}"}
        else:
            new = None
            if key is not None:
                if op == "bind-in":
                    new = (key, session.declare_subscriber(key, on_sample(port)))
                else:
                    new = (key, session.declare_publisher(key, encoding=zenoh.Encoding.APPLICATION_JSON))
            with lock:  # make before break: the new binding exists before the old goes
                old = table.pop(port, None)
                if new is not None:
                    table[port] = new
                reconfigurations += 1
            if old is not None:
                old[1].undeclare()
    elif op == "statistics":
        with lock:
            reply["statistics"] = {
                "uptime_ms": int((time.monotonic() - started) * 1000),
                "reconfigurations": reconfigurations,
                "cpu_ms": time.process_time() * 1000,
                "ports": stats,
            }
    elif op == "stop":
        done.set()
    else:
        reply = {"ok": False, "error": f"unknown op {op!r}"}
    query.reply(query.key_expr, json.dumps(reply))


def process_stat(pid):
    """The state and start time of process `pid` (fields 3 and 22 of /proc/PID/stat)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return fields[0], fields[19]
    except (OSError, IndexError):
        return None


def executor_runs():
    """Whether the executor named by DYKNOW_EXECUTOR_PROCESS ("pid:start time") still runs:
    a wrapper between it and this process (a shell) may outlive it."""
    identity = env.get("DYKNOW_EXECUTOR_PROCESS", "")
    pid, _, start = identity.partition(":")
    if not pid.isdigit() or not start:
        return True
    stat = process_stat(int(pid))
    return stat is not None and stat[0] != "Z" and stat[1] == start


def watch_parent():
    """Orphaned when the executor is gone (our parent changed, or the executor's process)."""
    parent = os.getppid()
    while not done.is_set():
        time.sleep(0.2)
        if os.getppid() != parent or not executor_runs():
            status["code"] = 2
            done.set()


if not executor_runs():
    sys.exit(2)  # started after the executor died: never run
# The executor's Zenoh configuration file (TLS certificates for tls/ endpoints) and lease.
config = (
    zenoh.Config.from_file(env["DYKNOW_ZENOH_CONFIG"])
    if env.get("DYKNOW_ZENOH_CONFIG")
    else zenoh.Config()
)
config.insert_json5("mode", '"client"')
config.insert_json5("connect/endpoints", json.dumps(CONNECT))
config.insert_json5("listen/endpoints", "[]")
config.insert_json5("scouting/multicast/enabled", "false")
if env.get("DYKNOW_ZENOH_LEASE_MS"):
    config.insert_json5("transport/link/tx/lease", str(int(env["DYKNOW_ZENOH_LEASE_MS"])))
session = zenoh.open(config)
queryable = session.declare_queryable(f"{CONTROL}/cu-control/*/{NAME}", control)
threading.Thread(target=watch_parent, daemon=True).start()
token = session.liveliness().declare_token(f"{CONTROL}/cu/*/{NAME}")
done.wait()
session.close()
sys.exit(status["code"])
