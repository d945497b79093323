//! The builtin transformations every executor has (`executors.md`): each a real computation.
//!
//! | name | in → out | parameters |
//! | --- | --- | --- |
//! | `dyknow/signal` | – → every out port | `period_ms` (100), `value` (default a counter 0, 1, 2, …) |
//! | `dyknow/relay` | each sample → every out port, unchanged | – |
//! | `dyknow/merge` | every in port → every out port, unchanged | – |
//! | `dyknow/throttle` | at most one sample per `period_ms` (1000) | `period_ms` |
//! | `dyknow/map` | numeric `value` → `value × scale + offset` | `scale` (1), `offset` (0) |
//! | `dyknow/threshold` | numeric `value` → `value ≥ threshold` | `threshold` (0) |
//! | `dyknow/replay` | – → one line of a JSON-lines file per `period_ms` | `file`, `period_ms` (100), `loop` (false), `retime` (true) |
//! | `dyknow/burn` | each sample, after `work` rounds of real arithmetic, unchanged | `work` (100000) |
//! | `dyknow/fault` | relays; crashes, exits or stalls on command or after `after` samples | `mode` (`panic`, `exit`, `error`, `stall`), `after`, `stall_ms` (10000) |
//!
//! Samples whose `value` is not a number are dropped by `map` and `threshold`. A fault
//! command is a sample whose value is `{"fault": "<mode>"}`.

use std::io::BufRead;
use std::time::{Duration, Instant};

use dyknow_cu::{CuError, NodeHandle, Sample, TimerId, Transformation, UnitSpec, now_ms};
use serde_json::Value;

/// Builds a transformation for a CU.
pub type Factory = fn(&UnitSpec, Host) -> Result<Box<dyn Transformation>, CuError>;

/// Where a builtin runs: `exit` means ending the process only in a process of its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Host {
    /// A thread inside an executor.
    Thread,
    /// A process of its own.
    Process,
}

/// The builtins, by name.
pub const BUILTINS: [(&str, Factory); 9] = [
    ("dyknow/signal", signal),
    ("dyknow/relay", relay),
    ("dyknow/merge", merge),
    ("dyknow/throttle", throttle),
    ("dyknow/map", map),
    ("dyknow/threshold", threshold),
    ("dyknow/replay", replay),
    ("dyknow/burn", burn),
    ("dyknow/fault", fault),
];

/// A builtin: one of [`BUILTINS`], or a stage of the simulated humanoid lab
/// ([`dyknow_lab::BUILTINS`]: `lab/…` and `nao/…`).
#[derive(Debug, Clone, Copy)]
pub enum Builtin {
    /// One of [`BUILTINS`].
    Core(Factory),
    /// A stage of the simulated lab.
    Lab(dyknow_lab::Factory),
}

impl Builtin {
    /// Builds the transformation of a CU.
    pub fn build(self, spec: &UnitSpec, host: Host) -> Result<Box<dyn Transformation>, CuError> {
        match self {
            Self::Core(f) => f(spec, host),
            Self::Lab(f) => f(spec),
        }
    }
}

/// The builtin called `name`.
pub fn builtin(name: &str) -> Option<Builtin> {
    BUILTINS
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, f)| Builtin::Core(*f))
        .or_else(|| {
            dyknow_lab::BUILTINS
                .iter()
                .find(|(n, _)| *n == name)
                .map(|(_, f)| Builtin::Lab(*f))
        })
}

/// The names of the builtins.
pub fn names() -> Vec<String> {
    BUILTINS
        .iter()
        .map(|(n, _)| (*n).to_owned())
        .chain(dyknow_lab::BUILTINS.iter().map(|(n, _)| (*n).to_owned()))
        .collect()
}

fn handle_params<'a>(spec: &'a UnitSpec) -> impl Fn(&str) -> Option<&'a Value> {
    |name| spec.params.get(name)
}

fn number(spec: &UnitSpec, name: &str, default: f64) -> Result<f64, CuError> {
    match handle_params(spec)(name) {
        None => Ok(default),
        Some(v) => v.as_f64().ok_or_else(|| CuError::Parameter {
            name: name.to_owned(),
            why: format!("{v} is not a number"),
        }),
    }
}

fn count(spec: &UnitSpec, name: &str, default: u64) -> Result<u64, CuError> {
    match handle_params(spec)(name) {
        None => Ok(default),
        Some(v) => v.as_u64().ok_or_else(|| CuError::Parameter {
            name: name.to_owned(),
            why: format!("{v} is not a non-negative integer"),
        }),
    }
}

fn needs_inputs(spec: &UnitSpec, what: &str) -> Result<(), CuError> {
    if spec.inputs.is_empty() {
        return Err(CuError::failed(format!("{what} needs an in port")));
    }
    Ok(())
}

struct Signal {
    period: Duration,
    value: Option<Value>,
    counter: u64,
}

fn signal(spec: &UnitSpec, _: Host) -> Result<Box<dyn Transformation>, CuError> {
    let period_ms = count(spec, "period_ms", 100)?;
    if period_ms == 0 {
        return Err(CuError::Parameter {
            name: "period_ms".into(),
            why: "must be at least 1".into(),
        });
    }
    Ok(Box::new(Signal {
        period: Duration::from_millis(period_ms),
        value: spec.params.get("value").cloned(),
        counter: 0,
    }))
}

impl Transformation for Signal {
    fn start(&mut self, cu: &mut NodeHandle<'_>) -> Result<(), CuError> {
        cu.every(self.period);
        Ok(())
    }

    fn on_sample(&mut self, _: &mut NodeHandle<'_>, _: &str, _: Sample) -> Result<(), CuError> {
        Ok(())
    }

    fn on_timer(&mut self, cu: &mut NodeHandle<'_>, _: TimerId) -> Result<(), CuError> {
        let value = self
            .value
            .clone()
            .unwrap_or_else(|| Value::from(self.counter));
        self.counter += 1;
        cu.publish_all(&Sample::new(now_ms(), value))
    }
}

struct Relay;

fn relay(spec: &UnitSpec, _: Host) -> Result<Box<dyn Transformation>, CuError> {
    needs_inputs(spec, "dyknow/relay")?;
    Ok(Box::new(Relay))
}

fn merge(spec: &UnitSpec, _: Host) -> Result<Box<dyn Transformation>, CuError> {
    needs_inputs(spec, "dyknow/merge")?;
    Ok(Box::new(Relay))
}

impl Transformation for Relay {
    fn on_sample(
        &mut self,
        cu: &mut NodeHandle<'_>,
        _: &str,
        sample: Sample,
    ) -> Result<(), CuError> {
        cu.forward_all(&sample)
    }
}

struct Throttle {
    period: Duration,
    last: Option<Instant>,
}

fn throttle(spec: &UnitSpec, _: Host) -> Result<Box<dyn Transformation>, CuError> {
    needs_inputs(spec, "dyknow/throttle")?;
    Ok(Box::new(Throttle {
        period: Duration::from_millis(count(spec, "period_ms", 1000)?),
        last: None,
    }))
}

impl Transformation for Throttle {
    fn on_sample(
        &mut self,
        cu: &mut NodeHandle<'_>,
        _: &str,
        sample: Sample,
    ) -> Result<(), CuError> {
        let now = Instant::now();
        if self
            .last
            .is_some_and(|last| now.duration_since(last) < self.period)
        {
            return Ok(());
        }
        self.last = Some(now);
        cu.forward_all(&sample)
    }
}

struct Map {
    scale: f64,
    offset: f64,
}

fn map(spec: &UnitSpec, _: Host) -> Result<Box<dyn Transformation>, CuError> {
    needs_inputs(spec, "dyknow/map")?;
    Ok(Box::new(Map {
        scale: number(spec, "scale", 1.0)?,
        offset: number(spec, "offset", 0.0)?,
    }))
}

impl Transformation for Map {
    fn on_sample(
        &mut self,
        cu: &mut NodeHandle<'_>,
        _: &str,
        sample: Sample,
    ) -> Result<(), CuError> {
        let Some(x) = sample.value.as_f64() else {
            return Ok(());
        };
        let y = x * self.scale + self.offset;
        if !y.is_finite() {
            // Past f64's range (1e308 × 10): JSON has no number for it, and `Value::from`
            // made it `null`, which went on down the chain as if it were a value.
            tracing::debug!(
                "{}: {x} × {} + {} is not a finite number: dropped",
                cu.name(),
                self.scale,
                self.offset
            );
            return Ok(());
        }
        // Integers stay integers when they can.
        let value = if y.fract() == 0.0 && y.abs() < 9.0e15 {
            #[allow(clippy::cast_possible_truncation)]
            Value::from(y as i64)
        } else {
            Value::from(y)
        };
        cu.publish_all(&Sample::new(sample.t, value))
    }
}

struct Threshold(f64);

fn threshold(spec: &UnitSpec, _: Host) -> Result<Box<dyn Transformation>, CuError> {
    needs_inputs(spec, "dyknow/threshold")?;
    Ok(Box::new(Threshold(number(spec, "threshold", 0.0)?)))
}

impl Transformation for Threshold {
    fn on_sample(
        &mut self,
        cu: &mut NodeHandle<'_>,
        _: &str,
        sample: Sample,
    ) -> Result<(), CuError> {
        let Some(x) = sample.value.as_f64() else {
            return Ok(());
        };
        cu.publish_all(&Sample::new(sample.t, x >= self.0))
    }
}

struct Replay {
    period: Duration,
    lines: Vec<Sample>,
    next: usize,
    looped: bool,
    retime: bool,
}

fn replay(spec: &UnitSpec, _: Host) -> Result<Box<dyn Transformation>, CuError> {
    let file = match spec.params.get("file") {
        Some(Value::String(f)) => f.clone(),
        _ => {
            return Err(CuError::Parameter {
                name: "file".into(),
                why: "dyknow/replay needs the path of a JSON-lines file".into(),
            });
        }
    };
    let reader = std::fs::File::open(&file).map_err(|e| CuError::Parameter {
        name: "file".into(),
        why: format!("{file}: {e}"),
    })?;
    let mut lines = Vec::new();
    for (n, line) in std::io::BufReader::new(reader).lines().enumerate() {
        let line = line.map_err(|e| CuError::failed(format!("{file}: {e}")))?;
        if line.trim().is_empty() {
            continue;
        }
        let value: Value = serde_json::from_str(&line)
            .map_err(|e| CuError::failed(format!("{file}:{}: {e}", n + 1)))?;
        // A line is a sample ({"t", "value"}) or a bare value.
        let sample = match serde_json::from_value::<Sample>(value.clone()) {
            Ok(sample) => sample,
            Err(_) => Sample::new(0, value),
        };
        lines.push(sample);
    }
    Ok(Box::new(Replay {
        period: Duration::from_millis(count(spec, "period_ms", 100)?.max(1)),
        lines,
        next: 0,
        looped: spec
            .params
            .get("loop")
            .and_then(Value::as_bool)
            .unwrap_or(false),
        retime: spec
            .params
            .get("retime")
            .and_then(Value::as_bool)
            .unwrap_or(true),
    }))
}

impl Transformation for Replay {
    fn start(&mut self, cu: &mut NodeHandle<'_>) -> Result<(), CuError> {
        cu.every(self.period);
        Ok(())
    }

    fn on_sample(&mut self, _: &mut NodeHandle<'_>, _: &str, _: Sample) -> Result<(), CuError> {
        Ok(())
    }

    fn on_timer(&mut self, cu: &mut NodeHandle<'_>, _: TimerId) -> Result<(), CuError> {
        if self.next >= self.lines.len() {
            if !self.looped || self.lines.is_empty() {
                return Ok(());
            }
            self.next = 0;
        }
        let mut sample = self.lines[self.next].clone();
        self.next += 1;
        if self.retime {
            sample.t = now_ms();
        }
        cu.publish_all(&sample)
    }
}

struct Burn(u64);

fn burn(spec: &UnitSpec, _: Host) -> Result<Box<dyn Transformation>, CuError> {
    needs_inputs(spec, "dyknow/burn")?;
    Ok(Box::new(Burn(count(spec, "work", 100_000)?)))
}

/// `rounds` of xorshift: real work the optimiser cannot remove.
pub fn work(rounds: u64, seed: u64) -> u64 {
    let mut x = seed | 1;
    for _ in 0..rounds {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
    }
    std::hint::black_box(x)
}

impl Transformation for Burn {
    fn on_sample(
        &mut self,
        cu: &mut NodeHandle<'_>,
        _: &str,
        sample: Sample,
    ) -> Result<(), CuError> {
        #[allow(clippy::cast_sign_loss)]
        work(self.0, sample.t as u64);
        cu.forward_all(&sample)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mode {
    Panic,
    Exit,
    Error,
    Stall,
}

impl Mode {
    fn parse(s: &str) -> Result<Self, CuError> {
        match s {
            "panic" => Ok(Self::Panic),
            "exit" => Ok(Self::Exit),
            "error" => Ok(Self::Error),
            "stall" => Ok(Self::Stall),
            other => Err(CuError::Parameter {
                name: "mode".into(),
                why: format!("{other:?} is not panic, exit, error or stall"),
            }),
        }
    }
}

struct Fault {
    mode: Mode,
    after: Option<u64>,
    stall: Duration,
    seen: u64,
    host: Host,
}

fn fault(spec: &UnitSpec, host: Host) -> Result<Box<dyn Transformation>, CuError> {
    let mode = match spec.params.get("mode") {
        None => Mode::Panic,
        Some(Value::String(s)) => Mode::parse(s)?,
        Some(v) => {
            return Err(CuError::Parameter {
                name: "mode".into(),
                why: format!("{v} is not a string"),
            });
        }
    };
    let after = match spec.params.get("after") {
        None => None,
        Some(_) => Some(count(spec, "after", 0)?),
    };
    let fault = Fault {
        mode,
        after,
        stall: Duration::from_millis(count(spec, "stall_ms", 10_000)?),
        seen: 0,
        host,
    };
    if fault.after == Some(0) {
        // Faults at start: the CU never runs.
        return Err(CuError::failed(format!(
            "fault injected at start ({mode:?})"
        )));
    }
    Ok(Box::new(fault))
}

impl Fault {
    fn strike(&self, mode: Mode) -> Result<(), CuError> {
        match mode {
            Mode::Panic => panic!("fault injected: panic"),
            Mode::Exit if self.host == Host::Process => std::process::exit(3),
            Mode::Exit => Err(CuError::failed("fault injected: exit")),
            Mode::Error => Err(CuError::failed("fault injected: error")),
            Mode::Stall => {
                std::thread::sleep(self.stall);
                Ok(())
            }
        }
    }
}

impl Transformation for Fault {
    fn on_sample(
        &mut self,
        cu: &mut NodeHandle<'_>,
        _: &str,
        sample: Sample,
    ) -> Result<(), CuError> {
        if let Some(Value::String(command)) = sample.value.get("fault") {
            let mode = Mode::parse(command)?;
            return self.strike(mode);
        }
        self.seen += 1;
        if self.after.is_some_and(|n| self.seen >= n) {
            self.strike(self.mode)?;
        }
        cu.forward_all(&sample)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use dyknow_cu::Collect;
    use serde_json::json;
    use std::collections::BTreeMap;

    fn spec(params: Value) -> UnitSpec {
        UnitSpec {
            name: "cu".into(),
            transformation: "t".into(),
            inputs: vec!["in".into()],
            outputs: vec!["out".into(), "copy".into()],
            params: serde_json::from_value::<BTreeMap<String, Value>>(params).expect("object"),
        }
    }

    /// Feeds `inputs` to a builtin and returns what it published.
    fn run(name: &str, params: Value, inputs: &[Value]) -> Result<Vec<(String, Sample)>, CuError> {
        let spec = spec(params);
        let mut t = builtin(name)
            .expect("a builtin")
            .build(&spec, Host::Thread)?;
        let mut out = Collect::default();
        let mut timers = Vec::new();
        for (i, value) in inputs.iter().enumerate() {
            let mut handle = NodeHandle::new(
                &spec.name,
                &spec.params,
                &spec.inputs,
                &spec.outputs,
                &mut out,
                &mut timers,
            );
            t.on_sample(&mut handle, "in", Sample::new(i as i64, value.clone()))?;
        }
        Ok(out.0)
    }

    #[test]
    fn relay_publishes_each_sample_unchanged_on_every_out_port() {
        let out = run("dyknow/relay", json!({}), &[json!(1), json!({"a": 2})]).expect("runs");
        assert_eq!(out.len(), 4);
        assert_eq!(out[0], ("out".into(), Sample::new(0, json!(1))));
        assert_eq!(out[1], ("copy".into(), Sample::new(0, json!(1))));
        assert_eq!(out[3].1, Sample::new(1, json!({"a": 2})));
    }

    #[test]
    fn map_and_threshold_compute() {
        let out = run(
            "dyknow/map",
            json!({"scale": 2, "offset": 0.5}),
            &[json!(3), json!("x")],
        )
        .expect("runs");
        assert_eq!(out[0].1.value, json!(6.5));
        assert_eq!(out.len(), 2, "a non-number is dropped");
        let out = run("dyknow/map", json!({"scale": 10}), &[json!(3)]).expect("runs");
        assert_eq!(out[0].1.value, json!(30));
        // Past f64's range: dropped, not published as `null` (a user audit saw 1e308 × 10
        // reach the next CU as null).
        let out = run(
            "dyknow/map",
            json!({"scale": 10}),
            &[json!(1e308), json!(1)],
        )
        .expect("runs");
        assert_eq!(
            out.iter().map(|(_, s)| s.value.clone()).collect::<Vec<_>>(),
            [json!(10), json!(10)],
            "only the second sample, on both out ports"
        );
        let out = run(
            "dyknow/threshold",
            json!({"threshold": 5}),
            &[json!(4), json!(5)],
        )
        .expect("runs");
        assert_eq!(out[0].1.value, json!(false));
        assert_eq!(out[2].1.value, json!(true));
        assert!(run("dyknow/map", json!({"scale": "big"}), &[]).is_err());
    }

    #[test]
    fn throttle_passes_one_sample_per_period() {
        let out = run(
            "dyknow/throttle",
            json!({"period_ms": 60000}),
            &[json!(1), json!(2), json!(3)],
        )
        .expect("runs");
        assert_eq!(out.len(), 2, "one sample, on two out ports");
    }

    #[test]
    fn faults_strike_after_n_samples_or_on_command() {
        let e = run(
            "dyknow/fault",
            json!({"mode": "error", "after": 2}),
            &[json!(1), json!(2)],
        )
        .expect_err("fails at the second sample");
        assert!(e.to_string().contains("fault injected"));
        let ok = run(
            "dyknow/fault",
            json!({"mode": "error", "after": 3}),
            &[json!(1), json!(2)],
        )
        .expect("two samples are fine");
        assert_eq!(ok.len(), 4);
        let e = run("dyknow/fault", json!({}), &[json!({"fault": "error"})]).expect_err("command");
        assert!(e.to_string().contains("error"));
        let panicked = std::panic::catch_unwind(|| {
            run(
                "dyknow/fault",
                json!({"mode": "panic", "after": 1}),
                &[json!(1)],
            )
        });
        assert!(panicked.is_err());
        assert!(run("dyknow/fault", json!({"mode": "meteor"}), &[]).is_err());
        assert!(
            run("dyknow/fault", json!({"after": 0}), &[]).is_err(),
            "fails at start"
        );
    }

    #[test]
    fn burn_does_work_and_relays() {
        assert_ne!(work(1000, 7), work(1001, 7));
        let out = run("dyknow/burn", json!({"work": 10}), &[json!(1)]).expect("runs");
        assert_eq!(out[0].1, Sample::new(0, json!(1)));
    }

    #[test]
    fn replay_reads_samples_and_bare_values() {
        let dir = std::env::temp_dir().join(format!("dyknow-replay-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let file = dir.join("r.jsonl");
        std::fs::write(&file, "{\"t\": 5, \"value\": 1}\n\n2\n").expect("write");
        let spec = spec(json!({"file": file.to_str(), "retime": false}));
        let mut t = builtin("dyknow/replay")
            .expect("replay")
            .build(&spec, Host::Thread)
            .expect("starts");
        let mut out = Collect::default();
        let mut timers = Vec::new();
        for _ in 0..3 {
            let mut handle = NodeHandle::new(
                &spec.name,
                &spec.params,
                &spec.inputs,
                &spec.outputs,
                &mut out,
                &mut timers,
            );
            t.on_timer(&mut handle, 0).expect("fires");
        }
        let values: Vec<_> = out
            .0
            .iter()
            .filter(|(p, _)| p == "out")
            .map(|(_, s)| s.clone())
            .collect();
        assert_eq!(
            values,
            [Sample::new(5, json!(1)), Sample::new(0, json!(2))],
            "no loop: two"
        );
        std::fs::write(&file, "not json\n").expect("write");
        assert!(
            builtin("dyknow/replay")
                .expect("replay")
                .build(&spec, Host::Thread)
                .is_err()
        );
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn builtins_refuse_missing_ports_and_bad_parameters() {
        let mut s = spec(json!({}));
        s.inputs.clear();
        assert!(
            builtin("dyknow/relay")
                .expect("relay")
                .build(&s, Host::Thread)
                .is_err()
        );
        assert!(
            builtin("dyknow/signal")
                .expect("signal")
                .build(&spec(json!({"period_ms": 0})), Host::Thread)
                .is_err()
        );
        assert!(builtin("dyknow/nope").is_none());
    }
}
