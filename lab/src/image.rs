//! Images as samples: raw pixel bytes, base64 in a JSON object (the sample format is JSON,
//! `executors.md`), with a seeded pixel noise generator.

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use dyknow_cu::CuError;
use serde_json::{Map, Value};

/// Encodes pixel bytes for a sample.
#[must_use]
pub fn encode(bytes: &[u8]) -> Value {
    Value::String(STANDARD.encode(bytes))
}

/// Decodes the pixel bytes of field `field` of `value`, which must hold `len` bytes.
pub fn decode(value: &Value, field: &str, len: usize) -> Result<Vec<u8>, CuError> {
    let text = value
        .get(field)
        .and_then(Value::as_str)
        .ok_or_else(|| bad(&format!("no {field:?} string")))?;
    let bytes = STANDARD
        .decode(text)
        .map_err(|e| bad(&format!("{field}: {e}")))?;
    if bytes.len() != len {
        return Err(bad(&format!(
            "{field}: {} bytes, expected {len}",
            bytes.len()
        )));
    }
    Ok(bytes)
}

/// A non-negative integer field of an image sample.
pub fn dimension(value: &Value, field: &str) -> Result<usize, CuError> {
    value
        .get(field)
        .and_then(Value::as_u64)
        .filter(|&n| n > 0 && n <= 8192)
        .map(|n| n as usize)
        .ok_or_else(|| bad(&format!("{field:?} is not an image dimension")))
}

/// A numeric field of a sample.
pub fn number(value: &Value, field: &str) -> Result<f64, CuError> {
    value
        .get(field)
        .and_then(Value::as_f64)
        .filter(|v| v.is_finite())
        .ok_or_else(|| bad(&format!("{field:?} is not a number")))
}

/// A sample the stage cannot read: the stage fails (a crash), as a real node would on
/// garbage input.
#[must_use]
pub fn bad(why: &str) -> CuError {
    CuError::failed(format!("malformed input: {why}"))
}

/// Builds a JSON object.
#[must_use]
pub fn object<const N: usize>(fields: [(&str, Value); N]) -> Value {
    let mut map = Map::new();
    for (k, v) in fields {
        map.insert(k.to_owned(), v);
    }
    Value::Object(map)
}

/// xorshift64*: the cameras' sensor noise, seeded per frame so a frame is reproducible.
#[derive(Debug, Clone)]
pub struct Noise(u64);

impl Noise {
    /// A generator seeded with `seed` (any value).
    #[must_use]
    pub fn new(seed: u64) -> Self {
        Self(seed | 1)
    }

    /// 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Adds noise of amplitude `±amp` (a power of two, at most 64) to every byte.
    pub fn apply(&mut self, bytes: &mut [u8], amp: u8) {
        let mask = u64::from(amp.max(1) * 2 - 1);
        let offset = i16::from(amp);
        for chunk in bytes.chunks_mut(8) {
            let mut r = self.next_u64();
            for b in chunk {
                let n = (r & mask) as i16 - offset;
                r >>= 8;
                *b = (i16::from(*b) + n).clamp(0, 255) as u8;
            }
        }
    }
}
