//! The web view at `/ui` in a real browser (Debian's chromium over WebDriver): the Chapter 6
//! lab posted through the *Library* panel, the graph following a crash and its repair without
//! moving, a rewiring through *Connect* showing in the change-set timeline, a bad Turtle file's
//! line and column, a group's verdict arriving live, and the bearer-token prompt. Each state is
//! a screenshot (`./dev screenshots` writes them to `docs/screenshots/`).
#![cfg(feature = "rocksdb")]
#![expect(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use serde_json::Value;

mod support;

use support::browser::Browser;
use support::*;

const MINUTE: Duration = Duration::from_secs(60);

fn spec_path(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../specs/turtle")
        .join(name)
        .canonicalize()
        .unwrap()
        .display()
        .to_string()
}

/// Opens the page and waits until it has drawn what the service has.
fn open(browser: &Browser, service: &Service) {
    browser.goto(&format!("{}/ui", service.url));
    browser.until(
        "the page to start",
        MINUTE,
        "return window.dyknowUi && document.getElementById('live').textContent === 'live'",
    );
}

/// Imports a Turtle file through the *Library* panel and returns the panel's answer box.
fn import(browser: &Browser, path: &str) -> String {
    browser.click("#tabs [data-panel=library]");
    browser.js("document.getElementById('import-result').replaceChildren(); return true");
    browser.type_into("#import-file", path);
    browser.click("#import-form button[type=submit]");
    browser
        .until(
            "the import's answer",
            MINUTE,
            "const r = document.querySelector('#import-result .ok-box, #import-result .error-box'); return r && r.innerText",
        )

        .as_str()
        .unwrap()
        .to_owned()
}

/// The CU nodes of the graph: name → {state, transformation, executor, x, y, fill}.
fn cu_nodes(browser: &Browser) -> BTreeMap<String, Value> {
    let v = browser
        .js("return dyknowUi.graph.cy.nodes('.cu').map(n => ({name: n.data('name'), state: n.data('state'), \
             transformation: n.data('transformation'), executor: n.data('executor'), x: n.position('x'), y: n.position('y'), \
             fill: n.style('background-color'), visible: n.visible()}))");
    v.as_array()
        .unwrap()
        .iter()
        .map(|n| (n["name"].as_str().unwrap().to_owned(), n.clone()))
        .collect()
}

/// The name of the (one) CU of `transformation`.
fn name_of(service: &Service, transformation: &str) -> String {
    service.cu_of(transformation).unwrap()["name"]
        .as_str()
        .unwrap()
        .to_owned()
}

/// Every node's position: id → (x, y).
fn positions(browser: &Browser) -> BTreeMap<String, (f64, f64)> {
    let v = browser.js("return dyknowUi.graph.positions()");
    v.as_object()
        .unwrap()
        .iter()
        .map(|(k, p)| {
            (
                k.clone(),
                (p["x"].as_f64().unwrap(), p["y"].as_f64().unwrap()),
            )
        })
        .collect()
}

/// The graph matches the service: a node per CU and per channel, an edge per bound port.
fn graph_matches(browser: &Browser, service: &Service) -> bool {
    let cus = service.get("/cus");
    let drawn = browser
        .js("const cy = dyknowUi.graph.cy; return {nodes: cy.nodes().map(n => n.id()), edges: cy.edges().map(e => [e.source().id(), e.target().id(), e.data('port')])}");
    let nodes: Vec<&str> = drawn["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    let edges: Vec<(String, String, String)> = drawn["edges"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                e[0].as_str().unwrap().to_owned(),
                e[1].as_str().unwrap().to_owned(),
                e[2].as_str().unwrap().to_owned(),
            )
        })
        .collect();
    for cu in cus.as_array().unwrap() {
        let id = format!("cu:{}", cu["name"].as_str().unwrap());
        if !nodes.contains(&id.as_str()) {
            return false;
        }
        for (dir, ports) in [("in", &cu["inputs"]), ("out", &cu["outputs"])] {
            for (port, ch) in ports.as_object().unwrap() {
                let Some(ch) = ch.as_str() else { continue };
                let ch = format!("ch:{ch}");
                let edge = if dir == "in" {
                    (ch, id.clone(), port.clone())
                } else {
                    (id.clone(), ch, port.clone())
                };
                if !edges.contains(&edge) {
                    return false;
                }
            }
        }
    }
    true
}

fn until_graph_matches(browser: &Browser, service: &Service, what: &str) {
    eventually(&format!("the graph to match: {what}"), MINUTE, || {
        graph_matches(browser, service).then_some(())
    });
}

const PIFF: [&str; 7] = [
    "pose(piff)",
    "bottom_cam(piff)",
    "subsampler(piff)",
    "segmenter(piff)",
    "ball_detector(piff)",
    "ball_localization(piff)",
    "circle_monitor(ball)",
];

#[test]
fn the_web_view_follows_the_live_lab() {
    let service = Service::start(&["--no-executor"]);
    let _piff = executor(&service, "piff");
    let browser = Browser::start();
    open(&browser, &service);

    // The Chapter 6 target and Piff's specs, imported through the Library panel.
    let answer = import(&browser, &spec_path("ch6-target.ttl"));
    assert!(answer.contains("targets target1"), "{answer}");
    browser
        .until(
            "the unsatisfied target on the graph",
            MINUTE,
            "const n = dyknowUi.graph.cy.getElementById('ch:/target_1'); return n.nonempty() && n.hasClass('unsatisfied')",
        );
    let answer = import(&browser, &spec_path("ch6-live-piff.ttl"));
    assert!(answer.contains("segmenter(piff)"), "{answer}");

    // The seven CUs, running on Piff's executor, and their channels.
    let nodes = browser
        .until(
            "seven running CUs",
            MINUTE,
            "const n = dyknowUi.graph.cy.nodes('.cu'); return n.length === 7 && n.every(x => x.data('state') === 'running') && n.length",
        );
    assert_eq!(nodes, 7);
    until_graph_matches(&browser, &service, "Piff's pipeline");
    let cus = cu_nodes(&browser);
    let mut drawn: Vec<&str> = cus
        .values()
        .map(|c| c["transformation"].as_str().unwrap())
        .collect();
    drawn.sort_unstable();
    let mut want = PIFF.to_vec();
    want.sort_unstable();
    assert_eq!(drawn, want);
    assert!(cus.values().all(|c| c["executor"] == "piff"));
    browser
        .until(
            "the target satisfied and a message rate on it",
            MINUTE,
            "const n = dyknowUi.graph.cy.getElementById('ch:/target_1'); return !n.hasClass('unsatisfied') && n.data('rate') > 0",
        );
    // The panels list them too.
    browser.click("#tabs [data-panel=active]");
    let rows = browser.until(
        "the Active panel",
        MINUTE,
        "const r = document.querySelectorAll('#active-rows tr'); return r.length === 7 && r.length",
    );
    assert_eq!(rows, 7);
    browser.js("dyknowUi.graph.fit(); return true");
    std::thread::sleep(Duration::from_millis(400)); // the fit's frame, for the picture only
    browser.shot("ui-chapter6");

    // kill -9 of the segmenter: its oval turns red where it was; the replacement appears next
    // to it and nothing else moves.
    let before = positions(&browser);
    let old = name_of(&service, "segmenter(piff)");
    let pid = service.get(&format!("/cus/{old}"))["pid"].as_u64().unwrap();
    Command::new("kill")
        .args(["-9", &pid.to_string()])
        .status()
        .unwrap();
    let red = browser.js(
        "return getComputedStyle(document.documentElement).getPropertyValue('--crashed').trim()",
    );
    let red = rgb(red.as_str().unwrap());
    // The fill fades to red in 0.3 s: polled until it is red.
    browser.until(
        "the crashed segmenter in red",
        MINUTE,
        &format!(
            "const n = dyknowUi.graph.cy.getElementById('cu:{old}'); return n.nonempty() && n.data('state') === 'crashed' && n.style('background-color') === '{red}'"
        ),
    );
    browser.shot("ui-crashed");
    let new = browser
        .until(
            "the replacement segmenter running",
            MINUTE,
            &format!(
                "const n = dyknowUi.graph.cy.nodes('.cu').filter(x => x.data('transformation') === 'segmenter(piff)' && x.data('name') !== '{old}' && x.data('state') === 'running'); return n.nonempty() && n.data('name')"
            ),
        )

        .as_str()
        .unwrap()
        .to_owned();
    until_graph_matches(&browser, &service, "the repaired pipeline");
    // Let a layout animation, if one had started, run to its end before measuring.
    std::thread::sleep(Duration::from_millis(600));
    let after = positions(&browser);
    let mut moved = 0.0_f64;
    for (id, (x, y)) in &before {
        if let Some((x2, y2)) = after.get(id) {
            moved = moved.max(((x2 - x).powi(2) + (y2 - y).powi(2)).sqrt());
        }
    }
    eprintln!("after the repair the other nodes moved at most {moved:.1} px");
    assert!(moved <= 3.0, "nodes moved {moved} px on the repair");
    assert!(after.contains_key(&format!("cu:{new}")));
    assert_eq!(
        after.get(&format!("cu:{old}")),
        before.get(&format!("cu:{old}")),
        "the crashed oval stays where it was"
    );
    browser.shot("ui-crash-repaired");

    // Connect: the ball detector's out port to a channel of our naming, then the localisation's
    // in port to it (two CUs' ports); both change sets appear in the timeline with cause manual.
    let detector = name_of(&service, "ball_detector(piff)");
    let localization = name_of(&service, "ball_localization(piff)");
    browser.click("#tabs [data-panel=connect]");
    browser.choose("#connect-cu", &detector);
    browser.choose("#connect-port", "out\u{0}pixelPos");
    browser.type_into("#connect-channel", "/piff/pixels");
    browser.click("#connect-form button[type=submit]");
    browser.until(
        "the detector publishing on /piff/pixels",
        MINUTE,
        "return dyknowUi.graph.cy.getElementById('ch:/piff/pixels').nonempty()",
    );
    browser.choose("#link-from", &format!("{detector}\u{0}pixelPos"));
    browser.choose("#link-to", &format!("{localization}\u{0}pixelPos"));
    browser.click("#link-form button[type=submit]");
    browser.click("#tabs [data-panel=changesets]");
    let timeline = browser
        .until(
            "both rewirings in the timeline",
            MINUTE,
            "const t = document.getElementById('timeline').innerText; return t.includes(`connect-in ${'LOC'} .pixelPos → /piff/pixels`) && t"
                .replace("LOC", &localization)
                .as_str(),
        );
    let timeline = timeline.as_str().unwrap();
    assert!(
        timeline.contains(&format!("connect-out {detector} .pixelPos → /piff/pixels")),
        "{timeline}"
    );
    assert!(timeline.contains("manual"), "{timeline}");
    until_graph_matches(&browser, &service, "the rewired pipeline");
    let consumer = browser
        .js("return dyknowUi.graph.cy.getElementById('ch:/piff/pixels').outgoers('node').map(n => n.data('name'))");
    assert_eq!(consumer, serde_json::json!([localization]));
    browser.shot("ui-connect-timeline");

    // A bad Turtle file: the API's line and column, and the offending line.
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.ttl");
    std::fs::write(
        &bad,
        "@prefix dyknow: <http://www.dyknow.eu/ontology/dyknow#> .\n\n[] a dyknow:Transformation ;\n   dyknow:hasName \"x\" \"y\" .\n",
    )
    .unwrap();
    let answer = import(&browser, bad.to_str().unwrap());
    assert!(answer.starts_with("bad.ttl: 400"), "{answer}");
    assert!(answer.contains("line 4, column"), "{answer}");
    assert!(answer.contains("dyknow:hasName \"x\" \"y\" ."), "{answer}");
    browser.shot("ui-bad-turtle");

    // A formula that does not parse: the API's 400 is shown, and stays through the list's
    // refreshes (it was put in the list, which the refresh right after redrew: never seen).
    browser.click("#tabs [data-panel=groups]");
    browser.type_into("#group-formulas", "always (p &&");
    browser.click("#group-form button[type=submit]");
    let error = browser.until(
        "the group's error",
        MINUTE,
        "const b = document.querySelector('#group-result .error-box'); return b && b.innerText",
    );
    assert!(error.as_str().unwrap().starts_with("group: 400"), "{error}");
    let shown = Instant::now();
    while shown.elapsed() < Duration::from_millis(2_500) {
        assert_eq!(
            browser.js("const b = document.querySelector('#group-result .error-box'); return b && b.innerText"),
            error,
            "the error went with a refresh"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    browser.js("document.getElementById('group-formulas').value = ''; return true");

    // A formula group over the lab's InsideCircle(ball): its verdict arrives live.
    browser.type_into("#group-label", "watch");
    browser.type_into(
        "#group-formulas",
        "eventually (InsideCircle(ball) or not InsideCircle(ball))",
    );
    browser.choose("#group-policy", "hold");
    // The one field is the max age under hold, the max delay otherwise.
    assert_eq!(
        browser.js("return document.getElementById('group-max-name').textContent"),
        "Max age ms"
    );
    browser.type_into("#group-max", "1000");
    browser.click("#group-form button[type=submit]");
    let verdict = browser
        .until(
            "the group's verdict",
            MINUTE,
            "const v = document.querySelector('[data-group=watch] [data-verdict]'); return v && v.dataset.verdict !== 'pending' && v.dataset.verdict",
        );
    assert_eq!(verdict, "true");
    // Created: the earlier error is gone.
    assert_eq!(
        browser.js("return document.getElementById('group-result').children.length"),
        0
    );
    let group = service.get("/groups/watch");
    assert_eq!(group["formulas"][0]["verdict"], "true", "{group}");
    assert_eq!(group["sync"]["max_age_ms"], 1000, "{group}");
    browser.shot("ui-groups");
    browser.click("#tabs [data-panel=active]");
    browser.until(
        "a CU publishing the symbol's channel in the Active panel",
        MINUTE,
        "return [...document.querySelectorAll('#active-rows td')].some(td => td.textContent.includes('/dyknow/symbols/'))",
    );
    // At 1280×800 the table fits its panel: every column, the state among them, in sight
    // (a symbol channel's name, `/dyknow/symbols/InsideCircle(ball)`, pushed it past the
    // window's edge).
    let fits = browser.js(
        "const p = document.getElementById('panel-active'); \
         const t = p.querySelector('table'); \
         return [t.getBoundingClientRect().right, p.getBoundingClientRect().right, window.innerWidth]",
    );
    let [table, panel, window] = [0, 1, 2].map(|i| fits[i].as_f64().unwrap());
    assert!(
        table <= panel + 0.5 && table <= window,
        "the Active table overflows: {fits}"
    );
    browser.click("#tabs [data-panel=groups]");
    // A stopped group takes no formula: its form is gone.
    assert_eq!(
        browser.js("return !!document.querySelector('[data-group=watch] form.add-formula')"),
        Value::Bool(true)
    );
    let stopped = agent()
        .post(&format!("{}/groups/watch/stop", service.url))
        .send_empty()
        .unwrap();
    assert_eq!(stopped.status().as_u16(), 200);
    browser.until(
        "the stopped group's form to go",
        MINUTE,
        "return !document.querySelector('[data-group=watch] form.add-formula')",
    );

    // Dark, at 1920×1080: the same page, for the docs.
    browser.resize(1920, 1080);
    browser.click("#theme-button");
    browser.click("#tabs [data-panel=active]");
    browser.js("dyknowUi.graph.fit(); return true");
    std::thread::sleep(Duration::from_millis(400)); // the fit's frame, for the picture only
    let theme = browser.js("return document.documentElement.dataset.theme");
    assert_eq!(theme, "dark");
    browser.shot("ui-dark-1920");
}

/// `#cf222e` → `rgb(207,34,46)` (cytoscape's computed colours).
fn rgb(hex: &str) -> String {
    let h = hex.trim_start_matches('#');
    let c = |i: usize| u8::from_str_radix(&h[i..i + 2], 16).unwrap();
    format!("rgb({},{},{})", c(0), c(2), c(4))
}

#[test]
fn changes_ask_for_the_token_and_a_401_is_shown() {
    let service = Service::start(&["--token", "s3cret"]);
    let browser = Browser::start();
    open(&browser, &service);
    browser.click("#tabs [data-panel=library]");
    browser.type_into("#import-file", &spec_path("ch6-target.ttl"));
    browser.click("#import-form button[type=submit]");
    // The server answers 401: the page asks for the token, saying why.
    let reason = browser
        .until(
            "the token prompt",
            MINUTE,
            "const d = document.getElementById('token-dialog'); return d.open && document.getElementById('token-reason').textContent",
        );
    assert!(
        reason.as_str().unwrap().starts_with("401 Unauthorized"),
        "{reason}"
    );
    browser.shot("ui-token-prompt");
    // A wrong token: the second 401 is shown as such, nothing is created.
    browser.type_into("#token-input", "wrong");
    browser.click("#token-ok");
    let answer = browser.until(
        "the 401",
        MINUTE,
        "const r = document.querySelector('#import-result .error-box'); return r && r.innerText",
    );
    assert!(
        answer.as_str().unwrap().contains("401 Unauthorized"),
        "{answer}"
    );
    assert_eq!(service.get("/targets"), serde_json::json!([]));
    // The right one, through the Token button: the import succeeds.
    browser.click("#token-button");
    browser.type_into("#token-input", "s3cret");
    browser.click("#token-ok");
    let answer = import(&browser, &spec_path("ch6-target.ttl"));
    assert!(answer.contains("targets target1"), "{answer}");
    assert_eq!(service.get("/targets")[0]["label"], "target1");
}

/// A change set whose review served several causes shows them all in the timeline, and every
/// CU its crash cause names (the first, `cu`, and the others of the burst, `also`) is drawn
/// crashed; before, only `cause.cu` was. Change sets made up in JavaScript, fed as the
/// change-set stream feeds them.
#[test]
fn every_cause_of_a_change_set_is_shown_and_every_crashed_cu_marked() {
    let service = Service::start(&["--model-only"]);
    let browser = Browser::start();
    open(&browser, &service);
    let out = browser.js(
        "const u = dyknowUi.ui;
         for (const cu of ['cu-a', 'cu-b', 'cu-c']) u.known.set(cu, {transformation: 't', executor: 'x'});
         dyknowUi.noteChangeSet({id: 'cs-900', at: new Date().toISOString(), actions: [],
           cause: {kind: 'cu-crashed', cu: 'cu-a', also: ['cu-b']},
           other_causes: [{kind: 'spec-changed', cus: ['cu-c']}, {kind: 'target-added', target: 'q1'}]}, false);
         return {crashed: [...u.crashed.keys()].sort(), destroyed: u.destroyed.has('cu-c')};",
    );
    assert_eq!(
        out,
        serde_json::json!({"crashed": ["cu-a", "cu-b"], "destroyed": true})
    );
    browser.click("#tabs [data-panel=changesets]");
    let cause = browser.until(
        "the change set in the timeline",
        MINUTE,
        "const c = document.querySelector('#timeline [data-id=\"cs-900\"] .cause'); return c && c.textContent",
    );
    assert_eq!(
        cause,
        "cu-crashed cu-a and 1 more, spec-changed cu-c, target-added q1"
    );
}

#[test]
fn the_page_and_its_libraries_are_served_from_the_binary() {
    let service = Service::start(&[]);
    let agent = agent();
    let page = agent
        .get(format!("{}/ui/", service.url))
        .call()
        .unwrap()
        .into_body()
        .read_to_string()
        .unwrap();
    assert!(page.contains("/ui/vendor/cytoscape.min.js"));
    for (path, media) in [
        ("/ui/app.js", "text/javascript"),
        ("/ui/vendor/cytoscape-dagre.min.js", "text/javascript"),
        ("/ui/style.css", "text/css"),
        ("/ui/vendor/LICENSE.cytoscape", "text/plain"),
    ] {
        let r = agent.get(format!("{}{path}", service.url)).call().unwrap();
        let ty = r.headers().get("content-type").unwrap().to_str().unwrap();
        assert!(ty.starts_with(media), "{path}: {ty}");
    }
    assert_eq!(service.status("/ui/nothing.js"), 404);
    assert_eq!(service.status("/ui/../Cargo.toml"), 404);
    // ?statistics=true adds each CU's statistics; anything else is a clear 400.
    assert_eq!(service.get("/cus?statistics=true"), serde_json::json!([]));
    assert_eq!(service.status("/cus?statistic=1"), 400);
}

/// Churn keeps the drawing compact: 120 chains (source → channel → map → target channel),
/// then 16 rounds each removing 30 chains and adding 30 new ones (a quarter of the nodes, so
/// the new nodes are placed beside their neighbours, not laid out afresh). A new chain takes
/// the room a removed one left, from a source of its own in the first layer; before, each was
/// put below everything, the drawing grew round after round (a user audit: 680 × 9,572 to
/// 38,975 × 22,287) until *Fit* could not show it. Run on a graph of its own in the page, with
/// views made up in JavaScript.
#[test]
fn the_drawing_stays_compact_under_churn() {
    let service = Service::start(&["--model-only"]);
    let browser = Browser::start();
    open(&browser, &service);
    let out = browser.js(
        "const div = document.createElement('div');
         div.style.cssText = 'position:fixed;left:0;top:0;width:1200px;height:800px;visibility:hidden';
         document.body.appendChild(div);
         const g = DyGraph.create(div, {});
         const chain = (i) => [
           {name: `s${i}`, transformation: 'src', state: 'running', inputs: {}, outputs: {out: `a${i}`}},
           {name: `m${i}`, transformation: 'map', state: 'running', inputs: {in: `a${i}`}, outputs: {out: `t${i}`}}];
         let live = [...Array(120).keys()];
         const view = () => ({cus: live.flatMap(chain),
           targets: live.map((i) => ({label: `q${i}`, channel: `t${i}`, satisfied: true})), crashed: []});
         const box = () => { const bb = g.cy.nodes().boundingBox(); return [bb.w, bb.h]; };
         g.update(view());
         const first = box();
         const rounds = [];
         let next = 1000;
         for (let round = 0; round < 16; round++) {
           live = live.filter((i, k) => k % 4 !== round % 4);
           g.update(view());
           for (let k = 0; k < 30; k++) live.push(next++);
           g.update(view());
           const [w, h] = box();
           rounds.push([w / first[0], h / first[1], g.metrics.relayouts || 0]);
         }
         return {first, rounds, nodes: g.cy.nodes().length};",
    );
    eprintln!("churn: {out}");
    assert_eq!(out["nodes"], 480, "{out}");
    let rounds: Vec<(f64, f64, u64)> = out["rounds"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            (
                r[0].as_f64().unwrap(),
                r[1].as_f64().unwrap(),
                r[2].as_u64().unwrap(),
            )
        })
        .collect();
    // The first six rounds: the new chains fill the holes (the height stays), placed beside
    // their neighbours, with no fresh layout; the width grows a little, since a placed chain's
    // layers are further apart than the layout's.
    for (w, h, relayouts) in &rounds[..6] {
        assert!(
            *w < 2.0 && *h < 1.1 && *relayouts == 0,
            "the drawing grew (width and height over the first drawing's, fresh layouts): {out}"
        );
    }
    // Whatever drift is left is bounded: four times as sparse as a fresh layout, it is laid
    // out afresh.
    for (w, h, _) in &rounds {
        assert!(w * h < 5.0, "{out}");
    }
}
