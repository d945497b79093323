//! Perturbations (seed Def. 36): what happens to the environment outside the life-cycle's own
//! change sets. Short-term negative ones (a target added or released, a CU lost) start a
//! review at once; registrations and deregistrations do when they leave the environment
//! invalid; the others wait for the end of the stable interval.

use dyknow_engine::{Cid, Qid, Tid};
use serde::{Deserialize, Serialize};

/// A perturbation, as `POST /perturbations` and the executors report them (`kind` in
/// kebab-case, as the contract spells `cu-crashed`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
#[non_exhaustive]
pub enum Perturbation {
    /// A CU crashed: it is removed from the model and a review starts at once, trying its
    /// transformation first (Ch. 4.3.3).
    CuCrashed {
        /// The CU.
        cu: Cid,
    },
    /// A target was added (AddTarget).
    TargetAdded {
        /// The target.
        target: Qid,
    },
    /// A target was released (RemoveTarget).
    TargetReleased {
        /// The target.
        target: Qid,
    },
    /// Transformations were registered (AddTransformation).
    Registered {
        /// Their labels.
        transformations: Vec<Tid>,
    },
    /// A transformation was deregistered (RemoveTransformation).
    Deregistered {
        /// Its label.
        transformation: Tid,
    },
    /// A review was asked for (`POST /review`).
    ReviewRequested,
}

impl Perturbation {
    /// Whether clients may report it through `POST /perturbations` (the others are what the
    /// service's own endpoints do).
    pub fn is_external(&self) -> bool {
        matches!(self, Self::CuCrashed { .. })
    }

    /// The `kind` names clients may report ([`Perturbation::is_external`]).
    pub const EXTERNAL_KINDS: [&'static str; 1] = ["cu-crashed"];

    /// The `kind` names of the perturbations, as JSON spells them.
    pub const KINDS: [&'static str; 6] = [
        "cu-crashed",
        "target-added",
        "target-released",
        "registered",
        "deregistered",
        "review-requested",
    ];
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn perturbations_read_as_the_contract_writes_them() {
        let p: Perturbation =
            serde_json::from_str(r#"{"kind": "cu-crashed", "cu": "cu-3"}"#).expect("parse");
        assert_eq!(p, Perturbation::CuCrashed { cu: "cu-3".into() });
        assert!(p.is_external());
        assert_eq!(Perturbation::EXTERNAL_KINDS, ["cu-crashed"]);
        for p in [
            Perturbation::TargetAdded { target: "q".into() },
            Perturbation::Registered {
                transformations: vec!["t".into()],
            },
            Perturbation::ReviewRequested,
        ] {
            let json = serde_json::to_value(&p).expect("serialise");
            assert!(Perturbation::KINDS.contains(&json["kind"].as_str().expect("a kind")));
            assert_eq!(
                serde_json::from_value::<Perturbation>(json).expect("parse"),
                p
            );
            assert!(!p.is_external());
        }
        assert!(serde_json::from_str::<Perturbation>(r#"{"kind": "meteor"}"#).is_err());
        assert!(
            serde_json::from_str::<Perturbation>(r#"{"kind": "cu-crashed", "cu": "a", "x": 1}"#)
                .is_err(),
            "unknown fields are refused"
        );
        assert!(serde_json::from_str::<Perturbation>(r#"{"kind": "cu-crashed"}"#).is_err());
    }
}
