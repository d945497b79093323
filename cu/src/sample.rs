//! Samples (`executors.md`): a Zenoh put with encoding `application/json` and the payload
//! `{"t": <valid time, ms since the Unix epoch>, "value": <any JSON>}`. Readers ignore fields
//! they do not know.

use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};
use serde_json::Value;

/// One sample of a stream. Read from a JSON object only: serde's derived reading of a struct
/// would take an array `[t, value]` too, which the contract's sample is not.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Sample {
    /// When the value holds, ms since the Unix epoch, set by the producing CU.
    pub t: i64,
    /// The value.
    pub value: Value,
}

impl<'de> Deserialize<'de> for Sample {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Fields;
        impl<'de> serde::de::Visitor<'de> for Fields {
            type Value = Sample;

            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("an object {\"t\": integer, \"value\": any}")
            }

            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> Result<Sample, A::Error> {
                use serde::de::Error;
                let (mut t, mut value) = (None, None);
                #[derive(Deserialize)]
                #[serde(field_identifier, rename_all = "lowercase")]
                enum Field {
                    T,
                    Value,
                    #[serde(other)]
                    Other,
                }
                while let Some(key) = map.next_key::<Field>()? {
                    match key {
                        Field::T if t.is_some() => return Err(A::Error::duplicate_field("t")),
                        Field::T => t = Some(map.next_value::<i64>()?),
                        Field::Value if value.is_some() => {
                            return Err(A::Error::duplicate_field("value"));
                        }
                        Field::Value => value = Some(map.next_value::<Value>()?),
                        // Readers ignore fields they do not know.
                        Field::Other => {
                            map.next_value::<serde::de::IgnoredAny>()?;
                        }
                    }
                }
                Ok(Sample {
                    t: t.ok_or_else(|| A::Error::missing_field("t"))?,
                    value: value.ok_or_else(|| A::Error::missing_field("value"))?,
                })
            }
        }
        deserializer.deserialize_map(Fields)
    }
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
            // The array serde reads a struct from, field by field: not a sample.
            b"[1, 2]",
            b"[1700000000000, {\"a\": 1}]",
            b"{\"t\": 1, \"t\": 2, \"value\": 0}",
            b"nope",
        ] {
            assert!(Sample::from_slice(bad).is_err(), "{bad:?}");
        }
    }
}
