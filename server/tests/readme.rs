//! The README's tour, run verbatim: every `$ ` command of its console blocks is executed with
//! bash against a fresh `dyknow serve --in-memory`, and its output must be what the README shows.

#![expect(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test harness: a failed set-up is a failed test"
)]

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

mod support;
use support::free_port;

/// (command, expected output) pairs of the tour section.
fn tour(readme: &str, name: &str) -> Vec<(String, String)> {
    let start = readme
        .find(&format!("<!-- {name}:start -->"))
        .expect("tour start marker");
    let end = readme
        .find(&format!("<!-- {name}:end -->"))
        .expect("tour end marker");
    let mut steps = Vec::new();
    let mut in_block = false;
    let mut current: Option<(String, String)> = None;
    let mut continued = false;
    for line in readme[start..end].lines() {
        if line.starts_with("```") {
            if in_block && let Some(step) = current.take() {
                steps.push(step);
            }
            in_block = line.trim() == "```console";
            continue;
        }
        if !in_block {
            continue;
        }
        if let Some(command) = line.strip_prefix("$ ") {
            if let Some(step) = current.take() {
                steps.push(step);
            }
            current = Some((command.to_owned(), String::new()));
            continued = command.contains("query=") && !command.trim_end().ends_with('\'');
        } else if let Some((command, output)) = current.as_mut() {
            if continued {
                command.push('\n');
                command.push_str(line);
                continued = !line.trim_end().ends_with('\'');
            } else {
                output.push_str(line);
                output.push('\n');
            }
        }
    }
    steps
}

#[test]
fn the_readme_tour_gives_the_answers_the_readme_shows() {
    run_tour("tour", &["--model-only"], &[], 6);
}

/// The tour of a pipeline that runs for real: the embedded executor on a Zenoh port of its
/// own, which the README's `dyknow listen` and `dyknow publish` find through `DYKNOW_ZENOH`.
#[test]
fn the_live_tour_runs_a_pipeline_and_repairs_it() {
    let zenoh = format!("tcp/127.0.0.1:{}", free_port());
    run_tour(
        "live-tour",
        &["--zenoh-listen", &zenoh],
        &[("DYKNOW_ZENOH", &zenoh)],
        7,
    );
}

/// Runs the console blocks between the `name` markers against a fresh `dyknow serve
/// --in-memory` started with `args`, with `env` set for the commands.
fn run_tour(name: &str, args: &[&str], env: &[(&str, &str)], at_least: usize) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
    let steps = tour(&readme, name);
    assert!(
        steps.len() >= at_least,
        "found only {} tour steps",
        steps.len()
    );

    let mut child = Killed(
        Command::new(env!("CARGO_BIN_EXE_dyknow"))
            .args(["serve", "--in-memory", "--bind", "127.0.0.1:0"])
            .args(args)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut lines = BufReader::new(child.0.stderr.take().unwrap()).lines();
    let deadline = Instant::now() + Duration::from_secs(60);
    let address = loop {
        assert!(Instant::now() < deadline, "server did not start");
        let line = lines.next().expect("server exited").unwrap();
        if let Some(rest) = line.split("listening on http://").nth(1) {
            break rest.split_whitespace().next().unwrap().to_owned();
        }
    };
    std::thread::spawn(move || for _ in lines {});

    let bin_dir = Path::new(env!("CARGO_BIN_EXE_dyknow"))
        .parent()
        .expect("the binary's directory");
    let path = format!(
        "{}:{}",
        bin_dir.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    for (command, expected) in steps {
        let command = command.replace("localhost:7878", &address);
        // A command that hangs (a listen that never gets its samples) fails, not blocks.
        let out = Command::new("timeout")
            .args(["120", "bash", "-c", &command])
            .env("PATH", &path)
            .envs(env.iter().copied())
            .current_dir(&root)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{command}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        // CSV results end lines with CRLF; the README shows them as lines.
        let got = String::from_utf8(out.stdout).unwrap().replace("\r\n", "\n");
        assert_eq!(
            got.trim_end(),
            expected.trim_end(),
            "the README's command\n{command}\nprinted something else"
        );
    }
    drop(child);
}

/// A child process killed when dropped: a failed step does not leave the service running.
struct Killed(std::process::Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
