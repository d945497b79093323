//! `dyknow explore` as a process: the seed's Example 12, both reviews, exactly; exit 1 when no
//! valid configuration exists; bad input.
#![expect(
    clippy::unwrap_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

const BIN: &str = env!("CARGO_BIN_EXE_dyknow");

fn spec(file: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../specs/turtle")
        .join(file)
}

fn explore(files: &[PathBuf], extra: &[&str]) -> (i32, Value, String) {
    let out = Command::new(BIN)
        .arg("explore")
        .args(extra)
        .args(files)
        .output()
        .unwrap();
    let json = serde_json::from_slice(&out.stdout).unwrap_or(Value::Null);
    (
        out.status.code().unwrap_or(-1),
        json,
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn spawned(cs: &Value) -> Vec<String> {
    cs["actions"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|a| a["action"] == "spawn")
        .map(|a| a["transformation"].as_str().unwrap().to_owned())
        .collect()
}

#[test]
fn example_12_both_reviews_through_the_cli() {
    let example = [
        spec("example-12-similarity.ttl"),
        spec("example-12.ttl"),
        spec("example-12-targets.ttl"),
    ];
    let (code, first, err) = explore(&example, &[]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(first["cost"]["total"], 33.0);
    assert_eq!(first["optimal"], true);
    assert_eq!(spawned(&first), ["tid1", "tid4", "tid2"]);
    assert_eq!(first["delta"]["delete"], "");

    // The environment after the first change set, with tid2's CU (cu-3) crashed and tid4's
    // upkeep observed as 3.0 (a learned estimate on its cost model).
    let insert = first["delta"]["insert"].as_str().unwrap();
    let mut environment: String = insert
        .lines()
        .filter(|l| !l.starts_with("<urn:dyknow:cu:cu-3"))
        .map(|l| format!("{l}\n"))
        .collect();
    environment.push_str(
        "<urn:dyknow:transformation:tid4/cost/upkeep> <http://www.dyknow.eu/ontology/dyknow-ros#historicalAverageUpkeep> \"3.0\"^^<http://www.w3.org/2001/XMLSchema#double> .\n\
         <urn:dyknow:transformation:tid4/cost/upkeep> <http://www.dyknow.eu/ontology/dyknow-ros#observationCount> \"1\"^^<http://www.w3.org/2001/XMLSchema#nonNegativeInteger> .\n",
    );
    let dir = tempfile::tempdir().unwrap();
    let env_file = dir.path().join("environment.nt");
    std::fs::write(&env_file, environment).unwrap();
    let mut files = example.to_vec();
    files.push(env_file);
    let (code, second, err) = explore(&files, &[]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(second["cost"]["total"], 43.0);
    assert_eq!(spawned(&second), ["tid3", "tid2", "tid5"]);
    let destroyed: Vec<&Value> = second["actions"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|a| a["action"] == "destroy")
        .collect();
    assert_eq!(destroyed.len(), 1);
    assert_eq!(destroyed[0]["cu"], "cu-2", "tid4's CU");
    assert!(
        second["delta"]["delete"]
            .as_str()
            .unwrap()
            .contains("<urn:dyknow:cu:cu-2>")
    );
}

#[test]
fn no_valid_configuration_exits_1_with_the_relaxed_change_set() {
    let (code, cs, err) = explore(
        &[
            spec("listing-5.3-undistort.ttl"),
            spec("listing-5.4-target.ttl"),
        ],
        &["--timeout-ms", "1000"],
    );
    assert_eq!(code, 1, "{err}");
    assert_eq!(
        cs["unsatisfied_targets"],
        serde_json::json!(["undistortSub"])
    );
    assert_eq!(cs["actions"], serde_json::json!([]));
    assert!(err.contains("undistortSub"), "{err}");
}

#[test]
fn bad_input_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.ttl");
    std::fs::write(&bad, "@prefix ex: <http://example.org/> .\nex:a ex:b .\n").unwrap();
    let (code, _, err) = explore(&[bad], &[]);
    assert_eq!(code, 2);
    assert!(err.contains("bad.ttl:2:"), "{err}");
    let (code, _, err) = explore(&[spec("example-12.ttl")], &["--horizon", "-1"]);
    assert_eq!(code, 2, "{err}");
}
