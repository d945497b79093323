//! `dyknow rcc8` as a process (contract `rcc8.md`): answers per instance, the refined network in
//! GQR's format, exit 1 on an inconsistent instance, `--exact`, bad input.
#![expect(
    clippy::unwrap_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::io::Write;
use std::process::{Command, Stdio};

const BIN: &str = env!("CARGO_BIN_EXE_dyknow");

fn rcc8(input: &str, extra: &[&str]) -> (i32, String, String) {
    let mut child = Command::new(BIN)
        .arg("rcc8")
        .args(extra)
        .arg("-")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // A usage error exits before reading its input: the pipe may then be closed.
    let _ = child.stdin.take().unwrap().write_all(input.as_bytes());
    let out = child.wait_with_output().unwrap();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8(out.stdout).unwrap(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// The seed's Example 7 (busy student: 0 student, 1 office, 2 canteen): DC(student, canteen)
/// is inferred; then GQR's not-path-consistent example.
#[test]
fn answers_each_instance() {
    let input = "2 # busy student\n0 1 ( NTTP )\n2 1 ( DC )\n.\n\
                 2\n0 1 ( TPP DC )\n1 2 ( TPP EC )\n0 2 ( TPPI EQ )\n.\n";
    let (code, out, stderr) = rcc8(input, &[]);
    assert_eq!(code, 1, "{stderr}");
    assert_eq!(
        out,
        "consistent\n2\n0 1 ( NTPP )\n0 2 ( DC )\n1 2 ( DC )\n.\ninconsistent\n"
    );
    let (code, out, _) = rcc8("2\n0 1 ( NTPP )\n2 1 ( DC )\n.\n", &[]);
    assert_eq!(code, 0);
    assert!(out.starts_with("consistent\n"));
}

/// Path consistency does not decide RCC-8 with arbitrary disjunctions; `--exact` does. Of GQR's
/// ten random instances in `example-10x20.csp`, four are path-consistent and two consistent.
#[test]
fn exact_decides_what_path_consistency_cannot() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../rcc8/tests/data/gqr-instances/example-10x20.csp"
    ))
    .unwrap();
    let count = |out: &str| out.lines().filter(|l| *l == "consistent").count();
    let (code, out, _) = rcc8(&text, &[]);
    assert_eq!((code, count(&out)), (1, 4));
    let (code, out, _) = rcc8(&text, &["--exact"]);
    assert_eq!((code, count(&out)), (1, 2));
}

#[test]
fn bad_input_names_line_and_column() {
    let (code, out, stderr) = rcc8("2\n0 1 ( DC XX )\n.\n", &[]);
    assert_eq!((code, out.as_str()), (2, ""));
    assert!(
        stderr.contains("line 2, column 10: 'XX' is not an RCC-8 relation"),
        "{stderr}"
    );
    let (code, _, stderr) = rcc8("1\n0 7 ( DC )\n.\n", &[]);
    assert_eq!(code, 2);
    assert!(stderr.contains("variable 7 beyond"), "{stderr}");
}

/// Bytes that are not UTF-8 are named by line and column, like any other bad input.
#[test]
fn bytes_that_are_not_utf8_are_located() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.csp");
    std::fs::write(&path, b"2\n0 1 ( DC \xff )\n.\n").unwrap();
    let out = Command::new(BIN).arg("rcc8").arg(&path).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("bad.csp: line 2, column 10: not UTF-8"),
        "{stderr}"
    );
}

/// Output to a pipe that was closed (`dyknow rcc8 f | head -1`) stops quietly (exit 0, nothing
/// on stderr): no panic (it was exit 101, "failed printing to stdout"), and no error (it was
/// exit 2, "writing the output: Broken pipe"). With stderr closed too (`2>&1 | head`), no panic
/// either (it was exit 101: "failed printing to stderr").
#[test]
fn a_closed_output_pipe_stops_quietly() {
    let mut input = String::from("1999\n");
    for i in 0..1999 {
        input.push_str(&format!("{i} {} ( NTPP )\n", i + 1));
    }
    input.push_str(".\n");
    for stderr_closed in [false, true] {
        let mut child = Command::new(BIN)
            .args(["rcc8", "-"])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // The reader goes away before anything is written.
        drop(child.stdout.take());
        if stderr_closed {
            drop(child.stderr.take());
        }
        let _ = child.stdin.take().unwrap().write_all(input.as_bytes());
        let out = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(
            (out.status.code(), stderr.as_ref()),
            (Some(0), ""),
            "stderr closed: {stderr_closed}"
        );
    }
}

/// The seed writes NTPP `NTTP` and its inverse `NTTP^-1` (matrix (3.21)): both are read, as
/// are `NTTPi` and `NTTPI`, like `NTPPi` and `NTPPI`.
#[test]
fn the_seeds_spelling_of_the_inverse_is_read() {
    for name in ["NTTP^-1", "NTTP ^-1", "NTTPi", "NTTPI"] {
        let (code, out, stderr) = rcc8(&format!("1\n0 1 ( {name} )\n.\n"), &[]);
        assert_eq!(
            (code, out.as_str()),
            (0, "consistent\n1\n0 1 ( NTPPI )\n.\n"),
            "{name}: {stderr}"
        );
    }
}

/// A file that starts with a UTF-8 byte order mark is read as without it (it was refused with
/// the invisible mark in the message: "found '\u{feff}2'").
#[test]
fn a_byte_order_mark_is_skipped() {
    let (code, out, stderr) = rcc8("\u{feff}2\n0 1 ( DC )\n.\n", &[]);
    assert_eq!(
        (code, out.as_str()),
        (0, "consistent\n2\n0 1 ( DC )\n.\n"),
        "{stderr}"
    );
}

/// A file with no instance (empty, or comments only) is bad input, not an answer: it printed
/// nothing and exited 0, as if every instance were consistent.
#[test]
fn a_file_without_an_instance_is_refused() {
    for text in ["", "# only a comment\n", "\n\n"] {
        let (code, out, stderr) = rcc8(text, &[]);
        assert_eq!((code, out.as_str()), (2, ""), "{text:?}: {stderr}");
        assert!(stderr.contains("no RCC-8 instance"), "{stderr}");
    }
}

/// `--exact --timeout`: an instance the search has not decided in time is `unknown`, followed
/// by its closure, and does not count as inconsistent (exit 0); given time, the same instance
/// is decided. `--timeout` needs `--exact` and a positive number (exit 2).
#[test]
fn a_time_limit_answers_unknown_with_the_closure() {
    let mut rng = dyknow_rcc8::generate::Rng(3);
    let net = dyknow_rcc8::generate::model_a(&mut rng, 600, 11.0, 5.0);
    let mut text = String::new();
    dyknow_rcc8::gqr::write(&net, &mut text).unwrap();
    let (_, closed, _) = rcc8(&text, &[]);
    assert!(closed.starts_with("consistent\n"), "{closed}");
    let (code, out, stderr) = rcc8(&text, &["--exact", "--timeout", "0.001"]);
    assert_eq!(code, 0, "{stderr}");
    assert_eq!(out.replacen("unknown", "consistent", 1), closed);
    assert!(stderr.contains("1 instance(s) undecided"), "{stderr}");
    let (code, out, stderr) = rcc8(&text, &["--exact", "--timeout", "60"]);
    assert_eq!(
        (code, out.lines().next()),
        (0, Some("consistent")),
        "{stderr}"
    );
    // A limit past what the clock can hold is no limit (it overflowed the deadline: a panic).
    let (code, out, stderr) = rcc8(&text, &["--exact", "--timeout", "1e19"]);
    assert_eq!(
        (code, out.lines().next()),
        (0, Some("consistent")),
        "{stderr}"
    );
    for bad in [
        &["--timeout", "1"][..],
        &["--exact", "--timeout", "0"],
        &["--exact", "--timeout", "x"],
    ] {
        let (code, out, _) = rcc8(&text, bad);
        assert_eq!((code, out.as_str()), (2, ""), "{bad:?}");
    }
    // A positive limit past what can be held is too large, and the message says so and what
    // the largest is (it said "a time limit is a positive number of seconds").
    let (code, out, stderr) = rcc8(&text, &["--exact", "--timeout", "1e20"]);
    assert_eq!((code, out.as_str()), (2, ""), "{stderr}");
    assert!(
        stderr.contains("too large") && stderr.contains(&u64::MAX.to_string()),
        "{stderr}"
    );
}
