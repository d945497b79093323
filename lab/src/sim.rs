//! Simulated sources for formula groups beyond the ball (the thesis' (4.5) and (5.12), and a
//! spatial scene): each value is a pure function of time and the parameters, so tests compare
//! verdicts with the truth, and several CUs of the same model agree.
//!
//! - `sim/uav_altitude`: a UAV flying at `altitude` m (default 60) that, from `drop_at_ms`
//!   (ms since the epoch), or `drop_after_ms` after the CU starts (never without either), descends at `descent` m/s (default 10) to the
//!   ground.
//! - `sim/battery`: a NAO's battery. From `start_ms` (default: when the CU starts) the level
//!   drains from `level` (default 0.3) at `drain` per second (default 0.05); `dock_ms` (default
//!   3000) after it falls below 0.1 the robot docks and charges at `charge` per second (default
//!   0.1) up to 1, then drains again. `quantity` says what the CU publishes: `level` (a number)
//!   or `charging` (a boolean).
//! - `sim/regions`: region `b` (a disc of radius 0.5) crossing region `a` (a disc of radius 1)
//!   along a line, from 3 m left to 3 m right of `a`'s centre at `speed` m/s (default 1) from
//!   `start_ms`, then back, forever; both lie inside the static region `field`. It publishes
//!   the RCC-8 constraints it observes: `[["a", "b", [R]], ["a", "field", ["NTPP"]], ["b",
//!   "field", ["NTPP"]]]` (names `a`, `b`, `field` by parameter).
//!
//! Every source ticks at `fps` (default 10).

use dyknow_cu::{CuError, UnitSpec, now_ms};
use serde_json::{Value, json};

use crate::stages::{Ticks, source};

fn number(spec: &UnitSpec, name: &str, default: f64) -> Result<f64, CuError> {
    match spec.params.get(name) {
        None => Ok(default),
        Some(v) => v
            .as_f64()
            .filter(|x| x.is_finite())
            .ok_or_else(|| CuError::Parameter {
                name: name.to_owned(),
                why: format!("{v} is not a number"),
            }),
    }
}

fn time(spec: &UnitSpec, name: &str) -> Result<Option<i64>, CuError> {
    match spec.params.get(name) {
        None => Ok(None),
        Some(v) => v.as_i64().map(Some).ok_or_else(|| CuError::Parameter {
            name: name.to_owned(),
            why: format!("{v} is not a time in ms since the epoch"),
        }),
    }
}

fn text(spec: &UnitSpec, name: &str, default: &str) -> Result<String, CuError> {
    match spec.params.get(name) {
        None => Ok(default.to_owned()),
        Some(Value::String(s)) => Ok(s.clone()),
        Some(v) => Err(CuError::Parameter {
            name: name.to_owned(),
            why: format!("{v} is not a string"),
        }),
    }
}

/// The UAV's altitude at `t`.
#[must_use]
pub fn altitude_at(altitude: f64, drop_at: Option<i64>, descent: f64, t: i64) -> f64 {
    match drop_at {
        Some(d) if t >= d => (altitude - descent * (t - d) as f64 / 1000.0).max(0.0),
        _ => altitude,
    }
}

/// `sim/uav_altitude`.
pub fn uav_altitude(spec: &UnitSpec) -> Result<Box<dyn dyknow_cu::Transformation>, CuError> {
    let altitude = number(spec, "altitude", 60.0)?;
    let descent = number(spec, "descent", 10.0)?;
    let drop_at = match time(spec, "drop_after_ms")? {
        Some(after) => Some(now_ms() + after),
        None => time(spec, "drop_at_ms")?,
    };
    source(Ticks::from_spec(spec, 10)?, move |t| {
        json!(altitude_at(altitude, drop_at, descent, t))
    })
}

/// The battery model of `sim/battery`.
#[derive(Debug, Clone, Copy)]
pub struct Battery {
    /// When the model starts (ms).
    pub start_ms: i64,
    /// The level then.
    pub level: f64,
    /// Drained per second.
    pub drain: f64,
    /// Charged per second.
    pub charge: f64,
    /// From below 0.1 to docking (ms).
    pub dock_ms: i64,
}

impl Battery {
    /// The level and whether it charges at `t`.
    #[must_use]
    pub fn at(&self, t: i64) -> (f64, bool) {
        let mut level = self.level;
        let mut now = self.start_ms;
        if t <= now {
            return (level, false);
        }
        loop {
            // Drain until 0.1, then dock_ms more (never below 0).
            let to_low = if level > 0.1 {
                (level - 0.1) / self.drain * 1000.0
            } else {
                0.0
            };
            let low_at = now + to_low.round() as i64;
            let dock_at = low_at + self.dock_ms;
            if t < dock_at {
                let l = level - self.drain * (t - now) as f64 / 1000.0;
                return (l.max(0.0), false);
            }
            let docked_level = (level - self.drain * (dock_at - now) as f64 / 1000.0).max(0.0);
            let full_at = dock_at + ((1.0 - docked_level) / self.charge * 1000.0).round() as i64;
            if t < full_at {
                return (
                    docked_level + self.charge * (t - dock_at) as f64 / 1000.0,
                    true,
                );
            }
            level = 1.0;
            now = full_at;
        }
    }
}

/// `sim/battery`.
pub fn battery(spec: &UnitSpec) -> Result<Box<dyn dyknow_cu::Transformation>, CuError> {
    let model = Battery {
        start_ms: time(spec, "start_ms")?.unwrap_or_else(now_ms),
        level: number(spec, "level", 0.3)?,
        drain: number(spec, "drain", 0.05)?.max(1e-6),
        charge: number(spec, "charge", 0.1)?.max(1e-6),
        dock_ms: time(spec, "dock_ms")?.unwrap_or(3000).max(0),
    };
    let charging = match text(spec, "quantity", "level")?.as_str() {
        "level" => false,
        "charging" => true,
        other => {
            return Err(CuError::Parameter {
                name: "quantity".into(),
                why: format!("{other:?} is not level or charging"),
            });
        }
    };
    source(Ticks::from_spec(spec, 10)?, move |t| {
        let (level, on) = model.at(t);
        if charging {
            json!(on)
        } else {
            json!((level * 1000.0).round() / 1000.0)
        }
    })
}

/// The RCC-8 relation of disc `a` (radius 1) to disc `b` (radius 0.5) `d` m apart.
#[must_use]
pub fn discs(d: f64) -> &'static str {
    let d = d.abs();
    if d > 1.5 {
        "DC"
    } else if d == 1.5 {
        "EC"
    } else if d > 0.5 {
        "PO"
    } else if d == 0.5 {
        "TPPI"
    } else {
        "NTPPI"
    }
}

/// Where `b` is (its distance from `a`'s centre, signed) at `t`.
#[must_use]
pub fn crossing(start_ms: i64, speed: f64, t: i64) -> f64 {
    let s = speed * (t - start_ms).max(0) as f64 / 1000.0;
    let s = s % 12.0;
    if s < 6.0 { s - 3.0 } else { 9.0 - s }
}

/// `sim/regions`.
pub fn regions(spec: &UnitSpec) -> Result<Box<dyn dyknow_cu::Transformation>, CuError> {
    let start = time(spec, "start_ms")?.unwrap_or_else(now_ms);
    let speed = number(spec, "speed", 1.0)?;
    let (a, b, field) = (
        text(spec, "a", "a")?,
        text(spec, "b", "b")?,
        text(spec, "field", "field")?,
    );
    source(Ticks::from_spec(spec, 10)?, move |t| {
        json!([
            [a, b, [discs(crossing(start, speed, t))]],
            [a, field, ["NTPP"]],
            [b, field, ["NTPP"]]
        ])
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_uav_holds_then_descends_to_the_ground() {
        assert_eq!(altitude_at(60.0, Some(1000), 10.0, 999), 60.0);
        assert_eq!(altitude_at(60.0, Some(1000), 10.0, 2000), 50.0);
        assert_eq!(altitude_at(60.0, Some(1000), 10.0, 100_000), 0.0);
        assert_eq!(altitude_at(60.0, None, 10.0, 100_000), 60.0);
    }

    #[test]
    fn the_battery_drains_docks_charges_and_drains_again() {
        let b = Battery {
            start_ms: 0,
            level: 0.3,
            drain: 0.1,
            charge: 0.5,
            dock_ms: 1000,
        };
        assert_eq!(b.at(0), (0.3, false));
        let (l, c) = b.at(1000);
        assert!((l - 0.2).abs() < 1e-9 && !c);
        // Below 0.1 at 2 s, docked at 3 s (level 0.0), full at 5 s.
        let (l, c) = b.at(2500);
        assert!((l - 0.05).abs() < 1e-9 && !c);
        let (l, c) = b.at(4000);
        assert!((l - 0.5).abs() < 1e-9 && c);
        let (l, c) = b.at(6000);
        assert!((l - 0.9).abs() < 1e-9 && !c, "{l}");
    }

    #[test]
    fn the_crossing_disc_goes_from_dc_through_po_to_ntppi_and_back() {
        let rel = |t| discs(crossing(0, 1.0, t));
        assert_eq!(rel(0), "DC");
        assert_eq!(rel(2000), "PO");
        assert_eq!(rel(3000), "NTPPI");
        assert_eq!(rel(4000), "PO");
        assert_eq!(rel(5000), "DC");
        assert_eq!(rel(9000), "NTPPI", "on the way back");
    }
}
