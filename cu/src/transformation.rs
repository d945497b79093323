//! What a transformation's code implements (the seed's nodelet with a `dyknow::NodeHandle`,
//! Listings 5.1–5.2): callbacks on named ports, timers and reconfiguration. The code never sees
//! a channel: the executor binds its ports.

use std::collections::BTreeMap;
use std::time::Duration;

use serde_json::Value;

use crate::error::CuError;
use crate::sample::Sample;

/// A timer's number, as [`NodeHandle::every`] returns it.
pub type TimerId = usize;

/// A transformation's implementation. One value serves one CU; its callbacks never run
/// concurrently. An `Err` or a panic from a callback crashes the CU.
pub trait Transformation: Send + 'static {
    /// Called once before the CU runs: read parameters, set timers.
    fn start(&mut self, cu: &mut NodeHandle<'_>) -> Result<(), CuError> {
        let _ = cu;
        Ok(())
    }

    /// A sample arrived on in port `port`.
    fn on_sample(
        &mut self,
        cu: &mut NodeHandle<'_>,
        port: &str,
        sample: Sample,
    ) -> Result<(), CuError>;

    /// Timer `timer` fired.
    fn on_timer(&mut self, cu: &mut NodeHandle<'_>, timer: TimerId) -> Result<(), CuError> {
        let _ = (cu, timer);
        Ok(())
    }

    /// A port was bound to another channel, or unbound (the seed's reconfiguration callback).
    fn on_reconfigure(&mut self, cu: &mut NodeHandle<'_>) -> Result<(), CuError> {
        let _ = cu;
        Ok(())
    }
}

/// Publishes on an out port: the host's side of [`NodeHandle::publish`].
pub trait Outputs {
    /// Publishes `sample` on `port`; a port bound to no channel drops it. Unknown ports are
    /// an error.
    fn publish(&mut self, port: &str, sample: &Sample) -> Result<(), CuError>;

    /// Publishes on `port` the sample the running callback received, unchanged. A host that
    /// kept the payload it received sends that as it is (no second serialisation, no copy);
    /// by default it is published like any sample.
    fn forward(&mut self, port: &str, sample: &Sample) -> Result<(), CuError> {
        self.publish(port, sample)
    }

    /// Whether `port` is bound to a channel.
    fn is_bound(&self, port: &str) -> bool;
}

/// [`Outputs`] that keep what is published, (port, sample) in order: for running a
/// transformation without a host, e.g. in its tests ([`NodeHandle::new`] over it).
#[derive(Debug, Default)]
pub struct Collect(pub Vec<(String, Sample)>);

impl Outputs for Collect {
    fn publish(&mut self, port: &str, sample: &Sample) -> Result<(), CuError> {
        self.0.push((port.to_owned(), sample.clone()));
        Ok(())
    }

    fn is_bound(&self, _: &str) -> bool {
        true
    }
}

/// A CU's view of itself during a callback (the seed's `dyknow::NodeHandle`).
pub struct NodeHandle<'a> {
    pub(crate) name: &'a str,
    pub(crate) params: &'a BTreeMap<String, Value>,
    pub(crate) inputs: &'a [String],
    pub(crate) outputs_names: &'a [String],
    pub(crate) outputs: &'a mut dyn Outputs,
    pub(crate) timers: &'a mut Vec<Duration>,
}

impl std::fmt::Debug for NodeHandle<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NodeHandle")
            .field("name", &self.name)
            .finish_non_exhaustive()
    }
}

impl<'a> NodeHandle<'a> {
    /// A handle over `outputs`: for hosts and tests.
    pub fn new(
        name: &'a str,
        params: &'a BTreeMap<String, Value>,
        inputs: &'a [String],
        outputs_names: &'a [String],
        outputs: &'a mut dyn Outputs,
        timers: &'a mut Vec<Duration>,
    ) -> Self {
        Self {
            name,
            params,
            inputs,
            outputs_names,
            outputs,
            timers,
        }
    }

    /// The CU's name.
    pub fn name(&self) -> &str {
        self.name
    }

    /// The in port names.
    pub fn inputs(&self) -> &[String] {
        self.inputs
    }

    /// The out port names.
    pub fn outputs(&self) -> &[String] {
        self.outputs_names
    }

    /// Publishes `value` on `port`, holding at `t`.
    pub fn publish(&mut self, port: &str, t: i64, value: impl Into<Value>) -> Result<(), CuError> {
        self.outputs.publish(port, &Sample::new(t, value))
    }

    /// Publishes a sample on `port`.
    pub fn publish_sample(&mut self, port: &str, sample: &Sample) -> Result<(), CuError> {
        self.outputs.publish(port, sample)
    }

    /// Publishes a sample on every out port.
    pub fn publish_all(&mut self, sample: &Sample) -> Result<(), CuError> {
        for port in self.outputs_names {
            self.outputs.publish(port, sample)?;
        }
        Ok(())
    }

    /// Publishes `sample`, the one this callback received, unchanged on every out port
    /// (relays, throttles, merges): the host may send the payload it received as it is, so a
    /// sample changed since must be published with [`Self::publish_all`] instead.
    pub fn forward_all(&mut self, sample: &Sample) -> Result<(), CuError> {
        for port in self.outputs_names {
            self.outputs.forward(port, sample)?;
        }
        Ok(())
    }

    /// Whether an out port is bound.
    pub fn is_bound(&self, port: &str) -> bool {
        self.outputs.is_bound(port)
    }

    /// A parameter (`dkros:hasParam`).
    pub fn param(&self, name: &str) -> Option<&Value> {
        self.params.get(name)
    }

    /// A numeric parameter, `default` when absent; an error when not a number.
    pub fn param_f64(&self, name: &str, default: f64) -> Result<f64, CuError> {
        match self.params.get(name) {
            None => Ok(default),
            Some(v) => v.as_f64().ok_or_else(|| CuError::Parameter {
                name: name.to_owned(),
                why: format!("{v} is not a number"),
            }),
        }
    }

    /// A non-negative integer parameter, `default` when absent.
    pub fn param_u64(&self, name: &str, default: u64) -> Result<u64, CuError> {
        match self.params.get(name) {
            None => Ok(default),
            Some(v) => v.as_u64().ok_or_else(|| CuError::Parameter {
                name: name.to_owned(),
                why: format!("{v} is not a non-negative integer"),
            }),
        }
    }

    /// A string parameter, if present; an error when not a string.
    pub fn param_str(&self, name: &str) -> Result<Option<&str>, CuError> {
        match self.params.get(name) {
            None => Ok(None),
            Some(Value::String(s)) => Ok(Some(s)),
            Some(v) => Err(CuError::Parameter {
                name: name.to_owned(),
                why: format!("{v} is not a string"),
            }),
        }
    }

    /// Asks for [`Transformation::on_timer`] every `period` (from [`Transformation::start`]);
    /// returns the timer's number. Timers tick on the wall clock's grid: at the multiples of
    /// `period` since the Unix epoch ([`crate::Timers::every`]).
    pub fn every(&mut self, period: Duration) -> TimerId {
        self.timers.push(period.max(Duration::from_micros(100)));
        self.timers.len() - 1
    }
}

impl Transformation for Box<dyn Transformation> {
    fn start(&mut self, cu: &mut NodeHandle<'_>) -> Result<(), CuError> {
        self.as_mut().start(cu)
    }

    fn on_sample(
        &mut self,
        cu: &mut NodeHandle<'_>,
        port: &str,
        sample: Sample,
    ) -> Result<(), CuError> {
        self.as_mut().on_sample(cu, port, sample)
    }

    fn on_timer(&mut self, cu: &mut NodeHandle<'_>, timer: TimerId) -> Result<(), CuError> {
        self.as_mut().on_timer(cu, timer)
    }

    fn on_reconfigure(&mut self, cu: &mut NodeHandle<'_>) -> Result<(), CuError> {
        self.as_mut().on_reconfigure(cu)
    }
}
