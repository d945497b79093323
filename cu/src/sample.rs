//! Samples (`executors.md`): a Zenoh put with encoding `application/json` and the payload
//! `{"t": <valid time, ms since the Unix epoch>, "value": <any JSON>}`. Readers ignore fields
//! they do not know.

use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};
use serde_json::Value;

/// One sample of a stream.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    /// When the value holds, ms since the Unix epoch, set by the producing CU.
    pub t: i64,
    /// The value.
    pub value: Value,
}

/// Why a payload is not a sample.
#[derive(Debug, thiserror::Error)]
#[error("not a DyKnow sample ({{\"t\": integer, \"value\": any}}): {0}")]
pub struct SampleError(#[from] serde_json::Error);

impl Sample {
    /// A sample holding at `t`.
    pub fn new(t: i64, value: impl Into<Value>) -> Self {
        Self {
            t,
            value: value.into(),
        }
    }

    /// A sample holding now.
    pub fn now(value: impl Into<Value>) -> Self {
        Self::new(now_ms(), value)
    }

    /// The JSON payload.
    pub fn to_bytes(&self) -> Vec<u8> {
        // A map of an integer and a JSON value always serialises.
        serde_json::to_vec(self).unwrap_or_default()
    }

    /// Reads a payload; unknown fields are ignored.
    pub fn from_slice(payload: &[u8]) -> Result<Self, SampleError> {
        Ok(serde_json::from_slice(payload)?)
    }
}

/// Milliseconds since the Unix epoch now.
pub fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_read_and_write_as_the_contract_says() {
        let s = Sample::from_slice(br#"{"t": 1700000000000, "value": [1, "a"], "extra": true}"#)
            .expect("a sample");
        assert_eq!(
            s,
            Sample::new(1_700_000_000_000, serde_json::json!([1, "a"]))
        );
        let back: Value = serde_json::from_slice(&s.to_bytes()).expect("json");
        assert_eq!(
            back,
            serde_json::json!({"t": 1_700_000_000_000_i64, "value": [1, "a"]})
        );
        for bad in [
            &b"{}"[..],
            b"{\"t\": 1.5, \"value\": 0}",
            b"{\"value\": 1}",
            b"[]",
            b"nope",
        ] {
            assert!(Sample::from_slice(bad).is_err(), "{bad:?}");
        }
    }
}
