#!/usr/bin/env python3
"""The thesis' Chapter 6 live: the simulated humanoid lab on one machine.

Starts `dyknow serve` (in memory, no embedded executor) and, step by step, the executors
`piff`, `puff` and `lab` as separate processes, and prints what the system does and why: each
change set's cause, actions and cost, the ball positions against the truth, the outage of each
repair. Stops everything it started at the end (or on Ctrl-C).

    python3 examples/lab_demo.py [--speed F] [--dyknow PATH]

--speed divides every pause between steps (default 1: about two minutes in all). Needs only the
`dyknow` binary (default: the one `./dev serve` builds) and Python's standard library.
"""
import argparse, json, os, signal, socket, subprocess, sys, time, urllib.parse, urllib.request

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SPECS = os.path.join(ROOT, "specs", "turtle")


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Demo:
    def __init__(self, binary, speed):
        self.bin, self.speed, self.procs = binary, speed, []
        self.http = free_port()
        self.zenoh = f"tcp/127.0.0.1:{free_port()}"
        self.url = f"http://127.0.0.1:{self.http}"
        self.seen = 0

    def start(self, *args):
        env = dict(os.environ, PATH=os.path.dirname(self.bin) + os.pathsep + os.environ.get("PATH", ""))
        env.setdefault("RUST_LOG", "warn")
        p = subprocess.Popen([self.bin, *args], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.procs.append(p)
        return p

    def call(self, method, path, body=None, ctype=None):
        req = urllib.request.Request(self.url + path, data=body, method=method)
        if ctype:
            req.add_header("Content-Type", ctype)
        with urllib.request.urlopen(req, timeout=60) as r:
            text = r.read().decode()
            return json.loads(text) if text else None

    def get(self, path):
        return self.call("GET", path)

    def post_spec(self, path, name):
        with open(os.path.join(SPECS, name), "rb") as f:
            return self.call("POST", path, f.read(), "text/turtle")

    def pause(self, seconds):
        time.sleep(seconds / self.speed)

    def wait(self, what, pred, timeout=60):
        end = time.time() + timeout
        while time.time() < end:
            v = pred()
            if v:
                return v
            time.sleep(0.05)
        raise SystemExit(f"timed out waiting for {what}")

    def running(self):
        return {c["transformation"]: c for c in self.get("/cus") if c["state"] == "running"}

    def show_change_sets(self):
        sets = self.get("/changesets")
        for c in sets[self.seen:]:
            acts = c["actions"]
            spawns = [a["transformation"] for a in acts if a["action"] == "spawn"]
            destroys = [a["cu"] for a in acts if a["action"] == "destroy"]
            cause = c["cause"]["kind"] + (f" of {c['cause']['cu']}" if "cu" in c["cause"] else "")
            cost = c["cost"]
            print(f"  change set {c['id']} ({c['status']}), cause: {cause}")
            if spawns:
                print(f"    spawn {len(spawns)}: {', '.join(spawns)}")
            if destroys:
                print(f"    destroy {len(destroys)}: {', '.join(destroys)}")
            if not acts:
                print("    no actions: the running configuration stays the cheapest")
            print(f"    estimated cost: labour {cost['labour']:.1f} + H {cost['horizon']:.0f} x upkeep "
                  f"{cost['upkeep_per_time_unit']:.1f} CPU ms/s = {cost['total']:.1f}")
        self.seen = len(sets)

    def upkeep(self, names):
        stats = self.get("/statistics")["transformations"]
        vals = [stats[n]["learned_upkeep"] for n in names]
        if all(v and v["observations"] >= 3 for v in vals):
            return sum(v["average"] for v in vals)
        return None

    def budget(self, names):
        """The specs' upkeep estimates of `names`, summed (CPU ms/s)."""
        return sum(self.get(f"/transformations/{urllib.parse.quote(n)}")["upkeep"] for n in names)

    def positions(self, channel, n=5):
        out = subprocess.run([self.bin, "listen", channel, "--connect", self.zenoh, "--count", str(n)],
                             capture_output=True, text=True, timeout=60).stdout
        for line in out.splitlines():
            s = json.loads(line)
            print(f"    t={s['t']}  ball at ({s['value']['x']:.2f}, {s['value']['y']:.2f}) m")

    def step(self, title):
        print(f"\n== {title}")

    def stop(self):
        for p in reversed(self.procs):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in self.procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--speed", type=float, default=1.0)
    ap.add_argument("--dyknow", default=os.path.join(os.environ.get("CARGO_TARGET_DIR",
                    os.path.expanduser("~/.cache/dyknow/target")), "release", "dyknow"))
    args = ap.parse_args()
    if args.speed <= 0:
        ap.error("--speed must be positive")
    d = Demo(os.path.abspath(args.dyknow), args.speed)
    try:
        run(d)
    finally:
        d.stop()


def run(d):
    d.start("serve", "--in-memory", "--no-executor", "--bind", f"127.0.0.1:{d.http}", "--zenoh-listen", d.zenoh)
    d.wait("the service", lambda: _up(d))
    d.step("6.2  The user asks for InsideCircle(ball) on /target_1; the lab's specs are known")
    d.post_spec("/targets", "ch6-target.ttl")
    for f in ["ch6-live-piff.ttl", "ch6-live-puff.ttl", "ch6-live-ceiling.ttl"]:
        d.post_spec("/transformations", f)
    print("  no executor is present, so no transformation can run: nothing runs")
    d.show_change_sets()
    d.pause(3)

    d.step("6.3-6.4  Piff's executor joins: its seven transformations become runnable")
    piff = d.start("executor", "--name", "piff", "--connect", d.zenoh)
    cus = d.wait("Piff's pipeline", lambda: (lambda r: r if len(r) == 7 else None)(d.running()))
    d.show_change_sets()
    channel = cus["circle_monitor(ball)"]["inputs"]["position"]
    print(f"  ball positions on {channel} (the circle monitor's input):")
    d.positions(channel)
    d.pause(5)

    d.step("6.5-6.6  Piff's segmenter (a process) is killed with kill -9")
    seg = cus["segmenter(piff)"]["name"]
    pid = d.get(f"/cus/{seg}")["pid"]
    os.kill(pid, signal.SIGKILL)
    t0 = time.time()
    d.wait("the repair", lambda: (lambda r: r.get("segmenter(piff)", {}).get("name") not in (None, seg))(d.running()))
    print(f"  executor reported the crash; the review spawned a new segmenter in {1000 * (time.time() - t0):.0f} ms")
    d.show_change_sets()
    d.pause(5)

    d.step("6.7  Puff joins: a second pipeline is possible, but switching costs labour and saves nothing")
    d.wait("Piff's measured upkeep", lambda: d.upkeep(PIFF))
    d.start("executor", "--name", "puff", "--connect", d.zenoh)
    d.wait("Puff", lambda: any(e["name"] == "puff" and e["present"] for e in d.get("/executors")))
    reviews = d.get("/environment")["reviews"]
    d.call("POST", "/review")
    d.wait("the review", lambda: (lambda e: e["reviews"] > reviews and e["phase"] == "stable"
                                  and not e["review_pending"])(d.get("/environment")))
    if len(d.get("/changesets")) == d.seen:
        print("  the review has no actions (no change set): the running configuration stays the cheapest")
    d.show_change_sets()
    print(f"  Piff's pipeline, measured: {d.upkeep(PIFF):.1f} CPU ms/s; Puff's budget: {d.budget(PUFF):.1f}")
    d.pause(5)

    d.step("6.8-6.10  Piff leaves (its executor is killed): Puff's pipeline takes over")
    piff.kill()
    cus = d.wait("Puff's pipeline", lambda: (lambda r: r if set(r) == set(PUFF) else None)(d.running()))
    d.show_change_sets()
    d.positions(cus["circle_monitor(ball,puff)"]["inputs"]["position"])
    d.pause(5)

    d.step("6.11-6.14  The lab's ceiling cameras join; once Puff's upkeep is measured, the review switches")
    puff_upkeep = d.wait("Puff's measured upkeep", lambda: d.upkeep(PUFF))
    print(f"  Puff's pipeline, measured: {puff_upkeep:.1f} CPU ms/s; the ceiling's budget: {d.budget(CEILING):.1f}")
    d.start("executor", "--name", "lab", "--connect", d.zenoh)
    want = set(CEILING) | {"circle_monitor(ball,puff)"}
    cus = d.wait("the ceiling pipeline", lambda: (lambda r: r if set(r) == want else None)(d.running()))
    d.show_change_sets()
    d.positions(cus["circle_monitor(ball,puff)"]["inputs"]["position"])
    ceiling = d.wait("the ceiling's measured upkeep", lambda: d.upkeep(CEILING + ["circle_monitor(ball,puff)"]))
    print(f"  measured now: ceiling + Puff's circle monitor {ceiling:.1f} CPU ms/s against Puff's {puff_upkeep:.1f}")
    d.pause(5)

    d.step("6.15-6.16  The target is released: every CU stops")
    d.call("DELETE", "/targets/target1")
    d.wait("every CU to stop", lambda: d.get("/cus") == [])
    d.show_change_sets()
    print("\nDone: the service and the executors stop now.")


def _up(d):
    try:
        return d.get("/executors") is not None
    except OSError:
        return False


PIFF = ["pose(piff)", "bottom_cam(piff)", "subsampler(piff)", "segmenter(piff)", "ball_detector(piff)",
        "ball_localization(piff)", "circle_monitor(ball)"]
PUFF = [t.replace("piff", "puff") for t in PIFF[:-1]] + ["circle_monitor(ball,puff)"]
CEILING = [f"{s}(cam_{i})" for i in range(1, 5) for s in ("ceiling_cam", "undistort")] + ["stitch(field)", "ball_detector(field)"]

if __name__ == "__main__":
    main()
