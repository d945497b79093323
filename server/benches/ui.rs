//! The web view under load (issue 16): 500 running CUs (50 chains of a `dyknow/signal` source
//! and nine `dyknow/relay`s, one target each) on one executor, drawn by `/ui` in headless
//! chromium. Measured in the browser: the first drawing, the time to apply a poll's update
//! (state, CPU and message rates of every CU), the time from a change set's event to the graph
//! showing it, and frame times while panning and zooming. The peer, side by side in the same
//! page: rebuilding the graph from scratch with a full dagre layout on every update (what a
//! view without in-place updates, like rqt_graph's refresh, does).
//!
//! `cargo bench -p dyknow-server --bench ui [-- --chains 50 --seconds 30]` (`./dev bench ui`).
#![cfg(feature = "rocksdb")]
#![expect(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "benchmark harness: a failed set-up is a failed run"
)]

use std::fmt::Write as _;
use std::time::{Duration, Instant};

use serde_json::Value;

#[path = "../tests/support/mod.rs"]
mod support;

use support::browser::Browser;
use support::{Service, executor};

fn arg(name: &str, default: u64) -> u64 {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .map_or(default, |v| v.parse().expect("a number"))
}

/// `chains` chains of ten: a source and nine relays, the last one's out tag a target.
fn specs(chains: u64) -> (String, String) {
    let mut tf = String::from(
        "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\
         @prefix dkros: <http://www.dyknow.eu/ontology/dyknow-ros#> .\n\
         @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n",
    );
    let mut targets = tf.clone();
    for k in 0..chains {
        writeln!(
            tf,
            "[] a dkros:ROSTransformation ; rdfs:label \"src{k}\" ; dkros:hasType \"builtin\" ; dkros:hasSource \"dyknow/signal\" ;\n\
             dkros:hasParam [ a dyknow:Parameter ; dyknow:hasName \"period_ms\" ; dyknow:hasValue 500 ] ;\n\
             dyknow:hasOutPort [ dyknow:hasName \"out\" ; dyknow:hasTag [ dyknow:hasValue \"S{k}x0\" ] ] ."
        )
        .unwrap();
        for i in 1..10 {
            writeln!(
                tf,
                "[] a dkros:ROSTransformation ; rdfs:label \"relay{k}x{i}\" ; dkros:hasType \"builtin\" ; dkros:hasSource \"dyknow/relay\" ;\n\
                 dyknow:hasInPort [ dyknow:hasName \"in\" ; dyknow:hasTag [ dyknow:hasValue \"S{k}x{}\" ] ] ;\n\
                 dyknow:hasOutPort [ dyknow:hasName \"out\" ; dyknow:hasTag [ dyknow:hasValue \"S{k}x{i}\" ] ] .",
                i - 1
            )
            .unwrap();
        }
        writeln!(
            targets,
            "[] a dkros:ROSTarget ; rdfs:label \"t{k}\" ;\n\
             dyknow:hasChannel [ a dkros:Topic ; dyknow:hasChannelName \"/chain/{k}\" ] ;\n\
             dyknow:hasTag [ a dyknow:Tag ; dyknow:hasValue \"S{k}x9\" ] ."
        )
        .unwrap();
    }
    (tf, targets)
}

fn stats(xs: &[f64]) -> (f64, f64, f64, usize) {
    let mut v = xs.to_vec();
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        return (f64::NAN, f64::NAN, f64::NAN, 0);
    }
    let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
    (q(0.5), q(0.95), v[v.len() - 1], v.len())
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_f64)
        .collect()
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let chains = arg("--chains", 50);
    let seconds = arg("--seconds", 30);
    let n = chains * 10;
    let service = Service::start(&["--no-executor"]);
    let _fleet = executor(&service, "fleet");
    let (tf, targets) = specs(chains);
    service.post("/transformations", &tf);
    service.post("/targets", &targets);
    let started = Instant::now();
    support::eventually("every CU running", Duration::from_secs(900), || {
        let cus = service.get("/cus");
        let cus = cus.as_array().unwrap();
        (cus.len() as u64 == n && cus.iter().all(|c| c["state"] == "running")).then_some(())
    });
    eprintln!(
        "{n} CUs running after {:.1} s",
        started.elapsed().as_secs_f64()
    );
    let t = Instant::now();
    let cus = service.get("/cus?statistics=true");
    let poll_ms = t.elapsed().as_secs_f64() * 1e3;
    let poll_bytes = cus.to_string().len();

    let browser = Browser::start();
    let t = Instant::now();
    browser.goto(&format!("{}/ui/", service.url));
    browser.until(
        "every CU drawn",
        Duration::from_secs(300),
        &format!("return window.dyknowUi && dyknowUi.graph.cy.nodes('.cu').length === {n}"),
    );
    let first_draw = t.elapsed().as_secs_f64() * 1e3;
    browser.js("dyknowUi.graph.fit(); return true");
    std::thread::sleep(Duration::from_millis(500)); // the fit's frame, for the picture only
    browser.shot("ui-500-cus");
    // The page's own cost of a poll, apart from the service's answer time: the last answer
    // with every CU's CPU time and rates changed (as a poll changes them), applied 20 times
    // through the same code path.
    let synthetic = browser.js("const ui = dyknowUi.ui, out = []; \
         for (let i = 0; i < 20; i++) { \
           const cus = ui.cus.map(c => Object.assign({}, c, {cpu: (c.cpu || 0) + i + 1, \
             rates: Object.fromEntries(Object.keys(c.rates || {}).map(p => [p, 2 + i / 10]))})); \
           out.push(dyknowUi.graph.update({cus, targets: ui.targets, crashed: ui.crashed})); } \
         return out");
    let synthetic = floats(&synthetic);
    // Updates at the page's own pace (one poll a second), while the CUs run.
    browser.js("dyknowUi.graph.metrics.updates.length = 0; return true");
    std::thread::sleep(Duration::from_secs(seconds));
    let updates = browser.js("return dyknowUi.graph.metrics.updates.map(u => u.ms)");
    let updates = floats(&updates);
    // Change sets: destroy two relays (not protected); each review replaces one. From the
    // change set's event to the graph showing it.
    browser.js("dyknowUi.ui.changeToGraph.length = 0; return true");
    for k in 0..2 {
        let name = service
            .get("/cus")
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["transformation"] == format!("relay{k}x5"))
            .unwrap()["name"]
            .as_str()
            .unwrap()
            .to_owned();
        let status = support::agent()
            .delete(format!("{}/cus/{name}", service.url))
            .call()
            .unwrap()
            .status();
        assert_eq!(status, 204);
        support::eventually("the replacement", Duration::from_secs(120), || {
            let cus = service.get("/cus");
            let cus = cus.as_array().unwrap();
            (cus.len() as u64 == n && cus.iter().all(|c| c["state"] == "running")).then_some(())
        });
    }
    browser.until(
        "the graph showing the replacements",
        Duration::from_secs(60),
        "return dyknowUi.ui.changeToGraph.length >= 2",
    );
    let change = floats(&browser.js("return dyknowUi.ui.changeToGraph"));
    // Frames while the user pans and zooms for five seconds.
    let frames = browser
        .js_async(
            "const done = arguments[arguments.length - 1]; const cy = dyknowUi.graph.cy; const out = []; \
             let last = performance.now(); const end = last + 5000; let i = 0; \
             function step(now) { out.push(now - last); last = now; i++; \
               cy.panBy({x: 3, y: 2}); cy.zoom({level: cy.zoom() * (i % 60 < 30 ? 1.01 : 0.99), renderedPosition: {x: 640, y: 400}}); \
               if (now < end) requestAnimationFrame(step); else done(out.slice(1)); } \
             requestAnimationFrame(step);",
        );
    let frames = floats(&frames);
    // The peer: every update rebuilt from scratch with a full layered layout.
    let rebuild = browser
        .js("const g = dyknowUi.graph, ui = dyknowUi.ui, cy = g.cy; const out = []; \
             for (let i = 0; i < 5; i++) { const t0 = performance.now(); \
               const defs = [...DyGraph.elements({cus: ui.cus, targets: ui.targets, crashed: ui.crashed}).values()]; \
               cy.batch(() => { cy.elements().remove(); cy.add(defs); }); \
               cy.layout({name: 'dagre', rankDir: 'LR', nodeSep: 18, rankSep: 45, animate: false, fit: false}).run(); \
               out.push(performance.now() - t0); } return out");
    let rebuild = floats(&rebuild);

    let (u50, u95, umax, un) = stats(&updates);
    let (r50, r95, rmax, rn) = stats(&rebuild);
    let (c50, c95, cmax, cn) = stats(&change);
    let (f50, f95, fmax, fnum) = stats(&frames);
    println!(
        "web view, {n} running CUs ({chains} chains of 10), chromium headless 1280x800, software rendering"
    );
    println!("| measure | n | p50 ms | p95 ms | max ms |");
    println!("| --- | --- | --- | --- | --- |");
    println!("| first drawing (page load to {n} CUs on screen) | 1 | {first_draw:.0} | | |");
    println!(
        "| GET /cus?statistics=true (from the bench, {poll_bytes} bytes) | 1 | {poll_ms:.1} | | |"
    );
    println!(
        "| apply a poll's update in place, live (ours) | {un} | {u50:.1} | {u95:.1} | {umax:.1} |"
    );
    let (s50, s95, smax, sn) = stats(&synthetic);
    println!(
        "| apply an update in place, every CU's CPU and rates changed (ours) | {sn} | {s50:.1} | {s95:.1} | {smax:.1} |"
    );
    println!("| rebuild + full dagre layout (peer) | {rn} | {r50:.1} | {r95:.1} | {rmax:.1} |");
    println!(
        "| change-set event to graph updated (fetch + apply) | {cn} | {c50:.1} | {c95:.1} | {cmax:.1} |"
    );
    println!(
        "| frame interval while panning and zooming | {fnum} | {f50:.1} | {f95:.1} | {fmax:.1} |"
    );
    println!(
        "peer/ours (p50, the 20 updates): {:.1}x; frames: {:.0} fps at p50",
        r50 / s50,
        1000.0 / f50
    );
}
