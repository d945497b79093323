//! When reviews run (seed Ch. 4.3, Def. 36): a review interval follows every stable interval
//! of H time units; a short-term negative perturbation (a target added or released, a CU lost)
//! ends the stable interval at once; a registration or deregistration does when it leaves the
//! environment invalid. Perturbations arriving during a review are queued: another review
//! follows.

use std::time::{Duration, SystemTime};

use dyknow_engine::{Cause, Tid};
use serde::Serialize;

use crate::manager::Settings;
use crate::perturbation::Perturbation;

/// Which interval of the life-cycle the service is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    /// Streams flow; the next review is scheduled.
    Stable,
    /// A review is running.
    Review,
}

/// Where the life-cycle is.
#[derive(Debug, Clone)]
pub struct Status {
    /// Stable or review.
    pub phase: Phase,
    /// When the next scheduled review starts.
    pub next_review_at: SystemTime,
    /// A review is due at once (queued behind a running one, or about to start).
    pub review_pending: bool,
    /// Reviews completed since the service started.
    pub reviews: u64,
    /// Why the last review failed, if it did.
    pub last_error: Option<String>,
}

/// The schedule's state, behind its own short-held lock.
#[derive(Debug)]
pub(crate) struct Schedule {
    settings: Settings,
    phase: Phase,
    next_review_at: SystemTime,
    /// A review is due at once.
    urgent: bool,
    /// A registration or deregistration asks whether the environment is still valid.
    check: bool,
    /// What perturbed the environment since the last review (the first one is the next
    /// change set's cause).
    causes: Vec<Cause>,
    /// Transformations of lost CUs, tried first (Ch. 4.3.3).
    prefer: Vec<Tid>,
    reviews: u64,
    last_error: Option<String>,
}

impl Schedule {
    pub(crate) fn new(settings: Settings) -> Self {
        Self {
            settings,
            phase: Phase::Stable,
            next_review_at: SystemTime::now() + settings.time_unit.mul_f64(settings.horizon),
            urgent: false,
            check: false,
            causes: Vec::new(),
            prefer: Vec::new(),
            reviews: 0,
            last_error: None,
        }
    }

    pub(crate) fn status(&self) -> Status {
        Status {
            phase: self.phase,
            next_review_at: self.next_review_at,
            review_pending: self.urgent,
            reviews: self.reviews,
            last_error: self.last_error.clone(),
        }
    }

    /// Records a perturbation: its cause, and whether a review is due at once or only if the
    /// environment is invalid.
    pub(crate) fn perturbed(&mut self, perturbation: &Perturbation) {
        let cause = match perturbation {
            Perturbation::CuCrashed { cu } => Some(Cause::CuCrashed { cu: cu.clone() }),
            Perturbation::TargetAdded { target } => Some(Cause::TargetAdded {
                target: target.clone(),
            }),
            Perturbation::TargetReleased { target } => Some(Cause::TargetReleased {
                target: target.clone(),
            }),
            Perturbation::ReviewRequested => Some(Cause::Review),
            Perturbation::Registered { .. } | Perturbation::Deregistered { .. } => {
                self.check = true;
                return;
            }
        };
        self.causes.extend(cause);
        self.urgent = true;
    }

    /// A review is due at once (a CU destroyed on request).
    pub(crate) fn urgent(&mut self) {
        self.urgent = true;
    }

    /// Tries `tid` first at the next review.
    pub(crate) fn prefer(&mut self, tid: Tid) {
        self.prefer.push(tid);
    }

    /// How long the loop may sleep.
    pub(crate) fn wait(&self) -> Duration {
        if self.urgent || self.check {
            Duration::ZERO
        } else {
            self.next_review_at
                .duration_since(SystemTime::now())
                .unwrap_or(Duration::ZERO)
        }
    }

    /// Whether a review is due (urgent, or the stable interval is over), and whether the
    /// environment's validity is to be checked; clears the check.
    pub(crate) fn due(&mut self) -> (bool, bool) {
        let due = self.urgent || SystemTime::now() >= self.next_review_at;
        (due, std::mem::take(&mut self.check))
    }

    /// A review starts: takes what perturbed the environment.
    pub(crate) fn review_starts(&mut self) -> (Vec<Cause>, Vec<Tid>) {
        self.urgent = false;
        self.check = false;
        self.phase = Phase::Review;
        (
            std::mem::take(&mut self.causes),
            std::mem::take(&mut self.prefer),
        )
    }

    /// A review ended; a failed one keeps its causes for the next attempt.
    pub(crate) fn review_ends(&mut self, causes: Vec<Cause>, error: Option<String>) {
        self.phase = Phase::Stable;
        self.reviews += 1;
        self.next_review_at =
            SystemTime::now() + self.settings.time_unit.mul_f64(self.settings.horizon);
        if error.is_some() {
            let mut kept = causes;
            kept.append(&mut self.causes);
            self.causes = kept;
        }
        self.last_error = error;
    }
}
