//! Access to the data plane (docs/reliability.md, "Access"): the manager's Zenoh listens on
//! loopback unless told otherwise; an endpoint other machines can reach is refused without
//! access control or mutual TLS; `--zenoh-config FILE` passes Zenoh's own configuration, and
//! an executor, its process CUs and a client run over mutual TLS with certificates this test
//! generates, while a client without a certificate is refused.
#![expect(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::process::{Command, Stdio};
use std::time::Duration;

use dyknow_cu::client_config_file;
use dyknow_cu::zenoh::{self, Wait};

mod support;

use support::*;

/// `dyknow <args>`: its exit code and standard error.
fn run(args: &[&str]) -> (Option<i32>, String) {
    let out = Command::new(BIN)
        .args(args)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn endpoints_other_machines_reach_are_refused_without_access_control() {
    let dir = tempfile::tempdir().unwrap();
    let exposed = format!("tcp/0.0.0.0:{}", free_port());
    let (code, stderr) = run(&[
        "serve",
        "--in-memory",
        "--bind",
        "127.0.0.1:0",
        "--zenoh-listen",
        &exposed,
    ]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(
        stderr.contains(&format!(
            "refusing to listen on the non-loopback Zenoh endpoint {exposed}"
        )),
        "{stderr}"
    );
    // The same rule for a stand-alone executor's own endpoint.
    let (code, stderr) = run(&[
        "executor",
        "--name",
        "e",
        "--connect",
        "tcp/127.0.0.1:9",
        "--listen",
        &exposed,
    ]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(stderr.contains("refusing to listen"), "{stderr}");
    // TLS without client certificates encrypts but lets anyone in: refused too.
    let certificates = Certificates::generate(dir.path());
    let tls_only = certificates.config(dir.path(), "tls-only.json5", false);
    let exposed_tls = format!("tls/0.0.0.0:{}", free_port());
    let (code, stderr) = run(&[
        "serve",
        "--in-memory",
        "--bind",
        "127.0.0.1:0",
        "--zenoh-listen",
        &exposed_tls,
        "--zenoh-config",
        tls_only.to_str().unwrap(),
    ]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(stderr.contains(&exposed_tls), "{stderr}");
    // A file that cannot be read is a clear error, not Zenoh's defaults.
    let (code, stderr) = run(&[
        "serve",
        "--in-memory",
        "--bind",
        "127.0.0.1:0",
        "--zenoh-config",
        "/nonexistent/zenoh.json5",
    ]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(
        stderr.contains("cannot read the Zenoh configuration /nonexistent/zenoh.json5"),
        "{stderr}"
    );
}

#[test]
fn an_executor_its_process_cus_and_a_client_run_over_mutual_tls() {
    let dir = tempfile::tempdir().unwrap();
    let certificates = Certificates::generate(dir.path());
    let mtls = certificates.config(dir.path(), "mtls.json5", true);
    let mtls_arg = mtls.to_str().unwrap();
    let endpoint = format!("tls/localhost:{}", free_port());
    // No embedded executor: every CU runs on the executor that joined over TLS.
    let service = Service::start_with(
        &["--in-memory"],
        &endpoint,
        &["--no-executor", "--zenoh-config", mtls_arg],
    );
    let _executor = executor_with(&endpoint, "tls-1", &["--zenoh-config", mtls_arg]);
    eventually("the TLS executor to join", Duration::from_secs(30), || {
        service
            .get("/executors")
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e["name"] == "tls-1" && e["present"] == true)
            .then_some(())
    });
    let process_map = format!("{BIN} cu dyknow/map");
    for spec in [
        counter(&[("period_ms", "20")]),
        // A process CU: it connects to its executor's endpoint, over TLS, with the
        // certificates of the executor's --zenoh-config (DYKNOW_ZENOH_CONFIG).
        tenfold(&process_map),
    ] {
        service.post("/transformations", &spec.turtle());
    }
    let client =
        zenoh::open(client_config_file(Some(&mtls), std::slice::from_ref(&endpoint)).unwrap())
            .wait()
            .unwrap();
    let out = Listener::new(&client, "/tenfold");
    service.post("/targets", &target("tenfold-q", "/tenfold", "Tenfold"));
    let (_, first) = out.next();
    let (_, second) = out.next();
    let a = first.value.as_i64().unwrap();
    assert_eq!(a % 10, 0, "{a} is a count times ten");
    assert_eq!(second.value.as_i64(), Some(a + 10));
    let tenfold = service.cu_of("tenfold").unwrap();
    assert_eq!(tenfold["executor"], "tls-1", "{tenfold}");

    // A client that trusts the service's certificate but has none of its own is refused.
    let anonymous = certificates.anonymous_config(dir.path());
    let refused =
        zenoh::open(client_config_file(Some(&anonymous), std::slice::from_ref(&endpoint)).unwrap())
            .wait();
    assert!(refused.is_err(), "a client without a certificate joined");
    // And one that speaks plain TCP to the TLS endpoint.
    let plain = endpoint.replacen("tls/", "tcp/", 1);
    assert!(
        zenoh::open(dyknow_cu::client_config(&[plain]).unwrap())
            .wait()
            .is_err(),
        "a plain TCP client joined a TLS endpoint"
    );
}

/// Zenoh's access control for a manager whose executors are `names`: denied by default; every
/// peer may carry streams, CU tokens and CU control, hear what the manager sends and ask; each
/// executor may speak on its own control keys only (its events, its services, its token), told
/// by the common name of its certificate.
fn acl(names: &[&str]) -> String {
    let all = r#""put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
        "liveliness_token", "declare_liveliness_subscriber", "liveliness_query""#;
    let mut rules = format!(
        r#"{{ id: "streams", messages: [{all}], flows: ["ingress", "egress"], permission: "allow",
             key_exprs: ["dyknow/channel/**", "dyknow/@dyknow/cu/*/*", "dyknow/@dyknow/cu-control/*/*"] }},
           {{ id: "from-manager", messages: [{all}], flows: ["egress"], permission: "allow",
             key_exprs: ["dyknow/@dyknow/**"] }},
           {{ id: "ask", messages: ["declare_subscriber", "query", "declare_liveliness_subscriber",
             "liveliness_query"], flows: ["ingress"], permission: "allow",
             key_exprs: ["dyknow/@dyknow/**"] }},"#
    );
    let mut subjects = String::new();
    let mut policies = format!(
        r#"{{ rules: ["streams", "from-manager", "ask"], subjects: [{}] }},"#,
        names
            .iter()
            .map(|n| format!("{n:?}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    for n in names {
        rules.push_str(&format!(
            r#"{{ id: "as-{n}", messages: ["put", "delete", "declare_queryable", "reply",
                 "liveliness_token"], flows: ["ingress"], permission: "allow",
                 key_exprs: ["dyknow/@dyknow/events/{n}", "dyknow/@dyknow/service/{n}/**",
                             "dyknow/@dyknow/executor/{n}/**"] }},"#
        ));
        subjects.push_str(&format!(r#"{{ id: "{n}", cert_common_names: ["{n}"] }},"#));
        policies.push_str(&format!(r#"{{ rules: ["as-{n}"], subjects: ["{n}"] }},"#));
    }
    format!(
        r#"access_control: {{ enabled: true, default_permission: "deny",
             rules: [{rules}], subjects: [{subjects}], policies: [{policies}] }},"#
    )
}

/// A manager over mutual TLS (with access control if `acl`), executor `a` running a counter, and
/// a peer holding executor `b`'s certificate that publishes, on `a`'s event key, that the counter
/// crashed. Whether the manager took the forged crash (a change set with cause `cu-crashed`).
fn forged_crash_is_taken(acl_on: bool) -> bool {
    let dir = tempfile::tempdir().unwrap();
    let authority = Authority::new(dir.path());
    let names = ["localhost", "127.0.0.1"];
    let manager = authority.issue("manager", &names);
    let extra = if acl_on {
        acl(&["a", "b"])
    } else {
        String::new()
    };
    let manager_config = manager.config_with(dir.path(), "manager.json5", true, &extra);
    let a = authority
        .issue("a", &names)
        .config(dir.path(), "a.json5", true);
    let b = authority
        .issue("b", &names)
        .config(dir.path(), "b.json5", true);
    let endpoint = format!("tls/localhost:{}", free_port());
    let service = Service::start_with(
        &["--in-memory"],
        &endpoint,
        &[
            "--no-executor",
            "--zenoh-config",
            manager_config.to_str().unwrap(),
        ],
    );
    let _a = executor_with(&endpoint, "a", &["--zenoh-config", a.to_str().unwrap()]);
    service.post(
        "/transformations",
        &counter(&[("period_ms", "20")]).turtle(),
    );
    service.post("/targets", &target("q", "/counts", "Count"));
    // Executor a's own messages pass: it joins, is asked to spawn, answers, reports it running.
    let cu = eventually("the counter to run on a", Duration::from_secs(30), || {
        service
            .cu_of("counter")
            .filter(|c| c["executor"] == "a" && service.get("/environment")["valid"] == true)
    });
    let name = cu["name"].as_str().unwrap().to_owned();
    let impostor =
        zenoh::open(client_config_file(Some(&b), std::slice::from_ref(&endpoint)).unwrap())
            .wait()
            .unwrap();
    let forged = serde_json::json!({
        "kind": "cu-crashed", "cu": name, "transformation": "counter", "reason": "forged"
    });
    let crashed = || {
        service
            .change_sets()
            .iter()
            .any(|c| c["cause"]["kind"] == "cu-crashed")
    };
    assert!(!crashed());
    // The forged crash, until the manager takes it or for 3 s (absence cannot be polled for).
    let deadline = std::time::Instant::now() + Duration::from_secs(3);
    while std::time::Instant::now() < deadline {
        impostor
            .put("dyknow/@dyknow/events/a", forged.to_string())
            .wait()
            .unwrap();
        if crashed() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    // Still a's, still running.
    assert_eq!(service.cu_of("counter").unwrap()["name"], name.as_str());
    false
}

#[test]
fn access_control_keeps_a_peer_from_speaking_for_another_executor() {
    // Mutual TLS alone lets any peer with a certificate report another executor's CU crashed.
    assert!(forged_crash_is_taken(false), "without access control");
    // With the access-control rules of docs/reliability.md it cannot.
    assert!(!forged_crash_is_taken(true), "with access control");
}
