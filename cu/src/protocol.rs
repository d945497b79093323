//! The messages between the manager and its executors, and between an executor and its
//! process CUs (`docs/executors.md`). All are JSON.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::keys::InstanceId;

/// What an executor runs for a transformation (`dkros:hasType`, `dkros:hasSource`,
/// `dkros:hasParam`, `dkros:hasExecutor`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Implementation {
    /// `builtin` (or the seed's `nodelet`) or `process`.
    pub kind: String,
    /// A builtin's name (`dyknow/relay`) or a command line.
    pub source: String,
    /// Parameters by name, as JSON (see [`param_value`]).
    #[serde(default)]
    pub params: BTreeMap<String, Value>,
    /// The executor the transformation is pinned to, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub executor: Option<String>,
    /// In port names.
    #[serde(default)]
    pub inputs: Vec<String>,
    /// Out port names.
    #[serde(default)]
    pub outputs: Vec<String>,
}

/// How an implementation runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A thread inside the executor (the seed's nodelet).
    Builtin,
    /// A child process speaking the CU protocol.
    Process,
}

impl Implementation {
    /// How it runs, or why it cannot.
    pub fn kind(&self) -> Result<Kind, String> {
        match self.kind.as_str() {
            "builtin" | "nodelet" => Ok(Kind::Builtin),
            "process" => Ok(Kind::Process),
            other => Err(format!(
                "dkros:hasType {other:?} is not an implementation kind (\"builtin\", \"nodelet\" or \"process\")"
            )),
        }
    }

    /// The command line of a process implementation, split at white space (an argument may
    /// be quoted with '"' to hold spaces).
    pub fn command(&self) -> Vec<String> {
        split_command(&self.source)
    }
}

/// Splits a command line at white space; `"..."` quotes an argument.
pub fn split_command(line: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut current = String::new();
    let mut quoted = false;
    let mut any = false;
    for c in line.chars() {
        match c {
            '"' => {
                quoted = !quoted;
                any = true;
            }
            c if c.is_whitespace() && !quoted => {
                if any {
                    out.push(std::mem::take(&mut current));
                    any = false;
                }
            }
            c => {
                current.push(c);
                any = true;
            }
        }
    }
    if any {
        out.push(current);
    }
    out
}

/// A parameter's value (`executors.md`): booleans and numbers as such, a string that parses as
/// JSON as that JSON, any other string as a string. `literal` is the lexical form and
/// `datatype` its XSD type's local name, if typed.
pub fn param_value(literal: &str, datatype: Option<&str>) -> Value {
    match datatype {
        Some("boolean") => match literal {
            "true" | "1" => return Value::Bool(true),
            "false" | "0" => return Value::Bool(false),
            _ => {}
        },
        Some(
            "integer" | "int" | "long" | "short" | "decimal" | "double" | "float"
            | "nonNegativeInteger" | "positiveInteger",
        ) => {
            if let Ok(v) = serde_json::from_str::<Value>(literal.trim())
                && v.is_number()
            {
                return v;
            }
        }
        _ => {}
    }
    serde_json::from_str(literal).unwrap_or_else(|_| Value::String(literal.to_owned()))
}

/// One action of a change set, as an executor applies it to one of its CUs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "action", rename_all = "kebab-case")]
pub enum CuAction {
    /// spawn: a CU of the implementation, every port unbound.
    Spawn {
        /// The CU.
        cu: String,
        /// Its transformation's label.
        transformation: String,
        /// What runs.
        implementation: Implementation,
    },
    /// destroy.
    Destroy {
        /// The CU.
        cu: String,
    },
    /// connect↓: an in port to a channel (make before break if bound).
    ConnectIn {
        /// The CU.
        cu: String,
        /// The port.
        port: String,
        /// The channel.
        channel: String,
    },
    /// connect↑: an out port to a channel.
    ConnectOut {
        /// The CU.
        cu: String,
        /// The port.
        port: String,
        /// The channel.
        channel: String,
    },
    /// disconnect↓.
    DisconnectIn {
        /// The CU.
        cu: String,
        /// The port.
        port: String,
    },
    /// disconnect↑.
    DisconnectOut {
        /// The CU.
        cu: String,
        /// The port.
        port: String,
    },
}

impl CuAction {
    /// The CU the action is about.
    pub fn cu(&self) -> &str {
        match self {
            Self::Spawn { cu, .. }
            | Self::Destroy { cu }
            | Self::ConnectIn { cu, .. }
            | Self::ConnectOut { cu, .. }
            | Self::DisconnectIn { cu, .. }
            | Self::DisconnectOut { cu, .. } => cu,
        }
    }

    /// The action's name (`spawn`, `connect-in`, …).
    pub fn kind(&self) -> &'static str {
        match self {
            Self::Spawn { .. } => "spawn",
            Self::Destroy { .. } => "destroy",
            Self::ConnectIn { .. } => "connect-in",
            Self::ConnectOut { .. } => "connect-out",
            Self::DisconnectIn { .. } => "disconnect-in",
            Self::DisconnectOut { .. } => "disconnect-out",
        }
    }
}

/// The manager's request to an executor: the actions of one change set for its CUs, in order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ApplyRequest {
    /// The change set's id.
    pub change_set: String,
    /// The change set's generation: its number in the manager's history, which only grows
    /// (`cs-7` → 7; 0 when unknown). The executor remembers, per CU, the generation of the
    /// last change set that configured it and refuses an older one's spawn or rebinding (a
    /// delayed or replayed request); destroying is always allowed.
    #[serde(default)]
    pub generation: u64,
    /// The actions.
    pub actions: Vec<CuAction>,
    /// The instance of the executor's name the request is for ([`ExecutorInfo::instance`]):
    /// another instance of the name refuses every action (two executors of one name meet
    /// when a partition heals; the later one steps down, and must not act meanwhile).
    /// Absent: any instance. (An executor from before 2026-11-29 ignores it.)
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub instance: Option<InstanceId>,
}

/// An action that failed.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Failure {
    /// Its index in [`ApplyRequest::actions`].
    pub index: usize,
    /// The CU.
    pub cu: String,
    /// Why.
    pub reason: String,
}

/// The executor's acknowledgement of an [`ApplyRequest`].
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ApplyReply {
    /// The actions that failed; after a failure the executor goes on with the actions of
    /// other CUs and skips the later actions of the failed CU.
    pub failures: Vec<Failure>,
}

/// A CU's life (`GET /cus/{name}`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CuState {
    /// Created, not yet running (a process that has not announced itself).
    Starting,
    /// Running.
    Running,
    /// Crashed: a panic, an exit, a kill, a lost executor.
    Crashed,
    /// Destroyed by a change set.
    Stopped,
    /// Model-only mode: nothing runs.
    Model,
}

/// The statistics of one port.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PortStatistics {
    /// Samples received (in port) or published (out port).
    pub messages: u64,
    /// Their payload bytes.
    pub bytes: u64,
    /// The `t` of the last one.
    pub last_t: Option<i64>,
}

/// A CU's statistics (the proxy's GetStatistics).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CuStatistics {
    /// Since it started running.
    pub uptime_ms: u64,
    /// Port rebindings since it was spawned.
    pub reconfigurations: u64,
    /// The CPU time of its callbacks (builtin) or its process.
    pub cpu_ms: f64,
    /// By port name.
    pub ports: BTreeMap<String, PortStatistics>,
}

/// A CU as its executor reports it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CuReport {
    /// The CU.
    pub cu: String,
    /// Its transformation.
    pub transformation: String,
    /// Its state.
    pub state: CuState,
    /// Port → channel, as bound.
    pub inputs: BTreeMap<String, Option<String>>,
    /// Port → channel, as bound.
    pub outputs: BTreeMap<String, Option<String>>,
    /// Its statistics.
    pub statistics: CuStatistics,
    /// Why it crashed, if it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// The process id of a process CU.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pid: Option<u32>,
    /// The generation of the last change set that configured it ([`ApplyRequest::generation`];
    /// 0 when unknown).
    #[serde(default)]
    pub generation: u64,
}

/// What an `info` query may ask (its payload; an empty payload asks everything).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct InfoRequest {
    /// With `false`, no process CU is asked for its statistics: each is reported with those
    /// it gave last (the manager's sweep asks only what runs, every few seconds).
    #[serde(default = "yes")]
    pub statistics: bool,
}

fn yes() -> bool {
    true
}

/// An executor's description (its `info` service).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExecutorInfo {
    /// Its name.
    pub name: String,
    /// The builtins it has.
    pub builtins: Vec<String>,
    /// Whether it runs process CUs.
    pub processes: bool,
    /// Its CUs.
    pub cus: Vec<CuReport>,
    /// Which instance of the name answers (absent from an executor that does not say: one
    /// from before 2026-11-29).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub instance: Option<InstanceId>,
}

/// The answer of an executor's `check` service for an [`Implementation`].
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CheckReply {
    /// Whether it can run it.
    pub runnable: bool,
    /// Why not.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub why: Option<String>,
}

/// What an executor reports without being asked (its `events` key).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Event {
    /// A CU is running; `labour_cpu_ms` is the CPU time spent creating it.
    Running {
        /// The CU.
        cu: String,
        /// Its transformation.
        transformation: String,
        /// Labour: CPU ms until it ran.
        labour_cpu_ms: f64,
    },
    /// A CU crashed.
    CuCrashed {
        /// The CU.
        cu: String,
        /// Its transformation.
        transformation: String,
        /// Why (a panic's message, an exit status).
        reason: String,
    },
    /// The CPU time a CU's callbacks used over an interval of wall time.
    Upkeep {
        /// The CU.
        cu: String,
        /// Its transformation.
        transformation: String,
        /// CPU ms used.
        cpu_ms: f64,
        /// Over this many wall ms.
        over_ms: f64,
    },
}

/// A request to a process CU's control service (`docs/executors.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "kebab-case")]
pub enum ControlRequest {
    /// Bind an in port to a channel (make before break), or unbind (`null`).
    BindIn {
        /// The port.
        port: String,
        /// The channel's name.
        channel: Option<String>,
        /// Its key expression (what a CU in another language subscribes to).
        key: Option<String>,
    },
    /// Bind an out port to a channel, or unbind (`null`).
    BindOut {
        /// The port.
        port: String,
        /// The channel's name.
        channel: Option<String>,
        /// Its key expression.
        key: Option<String>,
    },
    /// Report statistics.
    Statistics,
    /// Stop (exit 0).
    Stop,
}

/// A process CU's answer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ControlReply {
    /// Whether the request was carried out.
    pub ok: bool,
    /// Why not.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// The CU's statistics (for `statistics`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub statistics: Option<CuStatistics>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn parameters_read_as_the_contract_says() {
        assert_eq!(param_value("true", Some("boolean")), json!(true));
        assert_eq!(param_value("100", Some("integer")), json!(100));
        assert_eq!(param_value("100", None), json!(100));
        assert_eq!(param_value("2.5", Some("double")), json!(2.5));
        assert_eq!(
            param_value(r#"[["a","b",["PO"]]]"#, None),
            json!([["a", "b", ["PO"]]])
        );
        assert_eq!(param_value("/path/to/cam1/", None), json!("/path/to/cam1/"));
        assert_eq!(
            param_value("hello world", Some("string")),
            json!("hello world")
        );
    }

    #[test]
    fn command_lines_split_at_spaces_and_keep_quotes() {
        assert_eq!(
            split_command("python3  cu.py --x 1"),
            ["python3", "cu.py", "--x", "1"]
        );
        assert_eq!(split_command(r#"a "b c" """#), ["a", "b c", ""]);
        // The examples of docs/executors.md ("In any language").
        assert_eq!(
            split_command(r#"python3 "/opt/my cus/filter.py" --threshold 0.5"#),
            ["python3", "/opt/my cus/filter.py", "--threshold", "0.5"]
        );
        assert_eq!(
            split_command(r#"sh -c "exec python3 cu.py 2>>/tmp/cu.log""#),
            ["sh", "-c", "exec python3 cu.py 2>>/tmp/cu.log"]
        );
        assert_eq!(
            split_command(r#"a "b c"#),
            ["a", "b c"],
            "an open quote runs to the end"
        );
        assert!(split_command("   ").is_empty());
    }

    #[test]
    fn actions_are_kebab_case_json() {
        let a: CuAction = serde_json::from_value(
            json!({"action": "connect-in", "cu": "c", "port": "in", "channel": "x"}),
        )
        .expect("parse");
        assert_eq!(a.kind(), "connect-in");
        assert_eq!(a.cu(), "c");
    }
}
