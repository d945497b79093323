//! Learned cost estimates (seed Ch. 5.3.2): the historical average of the labour and upkeep
//! observed per transformation, which replaces a spec's initial estimate once there is an
//! observation (`LabourCostModel(historicalAverageLabour)`,
//! `UpkeepCostModel(historicalAverageUpkeep)`).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::ids::Tid;
use crate::model::Environment;

/// The largest cost a spec may give or an observation report (labour, or upkeep per time
/// unit). Costs are summed over CUs and multiplied by the horizon: with 1.7e308 the change
/// set's total became infinite, was written as `null`, and the record could not be read back
/// after a restart (its history lost). A trillion CPU milliseconds (about 32 years) per time
/// unit is far above any measured cost.
pub const MAX_COST: f64 = 1e12;

/// Whether `value` can be a cost: finite, non-negative and at most [`MAX_COST`].
pub fn valid_cost(value: f64) -> bool {
    value.is_finite() && (0.0..=MAX_COST).contains(&value)
}

/// A learned estimate: the historical average of the observations so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    /// The average.
    pub average: f64,
    /// How many observations it averages.
    pub count: u64,
}

impl Estimate {
    /// The estimate after one more observation (seed Eqs. 5.8–5.9, as a running mean).
    #[must_use]
    pub fn observe(self, value: f64) -> Self {
        let count = self.count + 1;
        Self {
            average: self.average + (value - self.average) / count as f64,
            count,
        }
    }
}

/// Which cost an observation is of.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CostKind {
    /// Labour: the cost of spawning one CU (Def. 31).
    Labour,
    /// Upkeep: the cost of one running CU per time unit (Def. 32).
    Upkeep,
}

/// Learned labour and upkeep estimates per transformation.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Learned {
    /// Labour (cost of one spawn).
    pub labour: BTreeMap<Tid, Estimate>,
    /// Upkeep (cost per time unit of one running CU).
    pub upkeep: BTreeMap<Tid, Estimate>,
}

impl Learned {
    /// Records one observation of `kind` for transformation `tid`.
    pub fn observe(&mut self, tid: Tid, kind: CostKind, value: f64) {
        let map = match kind {
            CostKind::Labour => &mut self.labour,
            CostKind::Upkeep => &mut self.upkeep,
        };
        let estimate = map.entry(tid).or_default();
        *estimate = estimate.observe(value);
    }

    /// Replaces the initial estimates of `env`'s library with the learned ones.
    pub fn apply(&self, env: &mut Environment) {
        for (tid, tf) in &mut env.library {
            if let Some(e) = self.labour.get(tid).filter(|e| e.count > 0) {
                tf.labour = e.average;
            }
            if let Some(e) = self.upkeep.get(tid).filter(|e| e.count > 0) {
                tf.upkeep = e.average;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_estimate_is_the_running_mean() {
        let mut learned = Learned::default();
        for v in [1.0, 2.0, 6.0] {
            learned.observe("t".into(), CostKind::Upkeep, v);
        }
        assert_eq!(
            learned.upkeep["t"],
            Estimate {
                average: 3.0,
                count: 3
            }
        );
        assert!(learned.labour.is_empty());
    }
}
