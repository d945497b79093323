//! When reviews run (seed Ch. 4.3, Def. 36): a review interval follows every stable interval
//! of H time units; a short-term negative perturbation (a target added or released, a CU lost)
//! ends the stable interval at once; a registration or deregistration does when it leaves the
//! environment invalid. Perturbations arriving during a review are queued: another review
//! follows. After a change set an executor could not apply, the next review waits a little,
//! longer after each failure in a row (from 100 ms, doubling, at most the stable interval), so
//! an executor that cannot run something is not asked again and again.

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant, SystemTime};

use dyknow_engine::{Cause, Cid, Qid, Tid};
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
    /// CU crashes recorded since the service started (each a perturbation; one reported
    /// twice, or of a CU the model no longer has, counts once or not at all).
    pub crashes: u64,
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
    /// A review is due because CUs crashed: at once, unless the last review started less than
    /// `review_spacing` ago (a crash storm is then coalesced into one review per spacing).
    crashed: bool,
    /// When the last review started.
    last_start: Option<Instant>,
    /// Registrations and deregistrations asking whether the environment is still valid:
    /// how many were reported, and up to which one the answer is known (a review answers all).
    checks_asked: u64,
    checks_done: u64,
    /// What perturbed the environment since the last review (the first one is the next
    /// change set's cause).
    causes: Vec<Cause>,
    /// Transformations of lost CUs, tried first (Ch. 4.3.3).
    prefer: Vec<Tid>,
    reviews: u64,
    crashes: u64,
    last_error: Option<String>,
    /// Change sets in a row with failed actions.
    failures_in_a_row: u32,
    /// Crashes a review could not repair, with the targets it left unsatisfied then: a later
    /// change set repairs the crash when it satisfies one of them.
    kept: BTreeMap<Cid, BTreeSet<Qid>>,
}

/// The wait before the review after the first failed change set; it doubles with each one in
/// a row.
const FIRST_RETRY: Duration = Duration::from_millis(100);

impl Schedule {
    pub(crate) fn new(settings: Settings) -> Self {
        Self {
            settings,
            phase: Phase::Stable,
            next_review_at: SystemTime::now() + settings.time_unit.mul_f64(settings.horizon),
            urgent: false,
            crashed: false,
            last_start: None,
            checks_asked: 0,
            checks_done: 0,
            causes: Vec::new(),
            prefer: Vec::new(),
            reviews: 0,
            crashes: 0,
            last_error: None,
            failures_in_a_row: 0,
            kept: BTreeMap::new(),
        }
    }

    fn stable_interval(&self) -> Duration {
        self.settings.time_unit.mul_f64(self.settings.horizon)
    }

    pub(crate) fn status(&self) -> Status {
        Status {
            phase: self.phase,
            next_review_at: self.next_review_at,
            review_pending: self.urgent || self.crashed || self.checks_asked > self.checks_done,
            reviews: self.reviews,
            crashes: self.crashes,
            last_error: self.last_error.clone(),
        }
    }

    /// Records a perturbation: its cause, and whether a review is due at once or only if the
    /// environment is invalid.
    pub(crate) fn perturbed(&mut self, perturbation: &Perturbation) {
        let cause = match perturbation {
            Perturbation::CuCrashed { cu } => {
                self.crashes += 1;
                self.causes.push(Cause::CuCrashed {
                    cu: cu.clone(),
                    also: Vec::new(),
                });
                self.crashed = true;
                return;
            }
            Perturbation::TargetAdded { target } => Some(Cause::TargetAdded {
                target: target.clone(),
            }),
            Perturbation::TargetReleased { target } => Some(Cause::TargetReleased {
                target: target.clone(),
            }),
            Perturbation::ReviewRequested => Some(Cause::Review),
            Perturbation::Registered { .. } | Perturbation::Deregistered { .. } => {
                self.checks_asked += 1;
                return;
            }
        };
        self.causes.extend(cause);
        self.urgent = true;
    }

    /// CUs left the model because their transformation's spec changed implementation: a
    /// review replaces them at once, with that as its cause (not a crash: the crash count is
    /// what shows a lost one).
    pub(crate) fn spec_changed(&mut self, cus: Vec<dyknow_engine::Cid>) {
        match self.causes.iter_mut().find_map(|c| match c {
            Cause::SpecChanged { cus } => Some(cus),
            _ => None,
        }) {
            Some(earlier) => earlier.extend(cus),
            None => self.causes.push(Cause::SpecChanged { cus }),
        }
        self.urgent = true;
    }

    /// A review is due at once (a CU destroyed on request).
    pub(crate) fn urgent(&mut self) {
        self.urgent = true;
    }

    /// A change set was applied in full: failures no longer count.
    pub(crate) fn applied(&mut self) {
        self.failures_in_a_row = 0;
    }

    /// An executor could not apply an action on `cu`, which is treated as crashed: the next
    /// review has the crash as its cause and comes after the back-off.
    pub(crate) fn failed(&mut self, cu: dyknow_engine::Cid) {
        self.causes.push(Cause::CuCrashed {
            cu,
            also: Vec::new(),
        });
        self.failures_in_a_row = self.failures_in_a_row.saturating_add(1);
        let wait = FIRST_RETRY
            .saturating_mul(1 << self.failures_in_a_row.saturating_sub(1).min(20))
            .min(self.stable_interval());
        self.next_review_at = self.next_review_at.min(SystemTime::now() + wait);
    }

    /// Tries `tid` first at the next review.
    pub(crate) fn prefer(&mut self, tid: Tid) {
        self.prefer.push(tid);
    }

    /// How long until crashes may start a review: what is left of `review_spacing` since the
    /// last review started.
    fn spacing_left(&self) -> Duration {
        self.last_start.map_or(Duration::ZERO, |start| {
            start
                .checked_add(self.settings.review_spacing)
                .map_or(self.settings.review_spacing, |t| {
                    t.saturating_duration_since(Instant::now())
                })
        })
    }

    /// How long the loop may sleep.
    pub(crate) fn wait(&self) -> Duration {
        let scheduled = self
            .next_review_at
            .duration_since(SystemTime::now())
            .unwrap_or(Duration::ZERO);
        if self.urgent || self.checks_asked > self.checks_done {
            Duration::ZERO
        } else if self.crashed {
            self.spacing_left().min(scheduled)
        } else {
            scheduled
        }
    }

    /// Whether a review is due (urgent, or the stable interval is over), and, if the
    /// environment's validity is to be checked, up to which check ([`Schedule::checked`]).
    pub(crate) fn due(&self) -> (bool, Option<u64>) {
        let due = self.urgent
            || (self.crashed && self.spacing_left().is_zero())
            || SystemTime::now() >= self.next_review_at;
        let check = (self.checks_asked > self.checks_done).then_some(self.checks_asked);
        (due, check)
    }

    /// The checks up to `upto` found the environment valid: no review.
    pub(crate) fn checked(&mut self, upto: u64) {
        self.checks_done = self.checks_done.max(upto);
    }

    /// A review starts: takes what perturbed the environment.
    pub(crate) fn review_starts(&mut self) -> (Vec<Cause>, Vec<Tid>) {
        self.urgent = false;
        self.crashed = false;
        self.last_start = Some(Instant::now());
        // The next regular review is a stable interval away; a failure while this one runs
        // brings it forward by the back-off only (from a time in the past, the back-off would
        // be no wait at all).
        self.next_review_at = SystemTime::now() + self.stable_interval();
        self.checks_done = self.checks_asked;
        self.phase = Phase::Review;
        (
            std::mem::take(&mut self.causes),
            std::mem::take(&mut self.prefer),
        )
    }

    /// A review could not repair the crashes among `causes` (nothing can run their
    /// transformations now) and left `unsatisfied` unsatisfied: the next change set that
    /// satisfies one of those targets has them as its cause, ahead of what came meanwhile.
    /// They start no review themselves.
    pub(crate) fn keep_crashes(&mut self, causes: &[Cause], unsatisfied: &[Qid]) {
        let crashes: Vec<Cause> = causes
            .iter()
            .filter(|c| matches!(c, Cause::CuCrashed { .. }))
            .cloned()
            .collect();
        for crash in &crashes {
            // The targets of the first review that could not repair it: those it left
            // unsatisfied (a later review's may hold others, unsatisfied for other reasons).
            if let Cause::CuCrashed { cu, .. } = crash {
                self.kept
                    .entry(cu.clone())
                    .or_insert_with(|| unsatisfied.iter().cloned().collect());
            }
        }
        self.causes.splice(0..0, crashes);
    }

    /// Of `causes`, the crashes kept earlier ([`Schedule::keep_crashes`]) that a change set
    /// leaving `unsatisfied` unsatisfied does not repair (every target they left unsatisfied
    /// still is): they are kept for a later one, which they remain the cause of; the change
    /// set is not theirs. The others are repaired and forgotten.
    pub(crate) fn unrepaired(&mut self, causes: &[Cause], unsatisfied: &[Qid]) -> Vec<Cause> {
        let still: BTreeSet<&Qid> = unsatisfied.iter().collect();
        let mut out = Vec::new();
        for cause in causes {
            let Cause::CuCrashed { cu, .. } = cause else {
                continue;
            };
            match self.kept.get(cu) {
                Some(targets)
                    if !targets.is_empty() && targets.iter().all(|q| still.contains(q)) =>
                {
                    out.push(cause.clone());
                }
                _ => {
                    self.kept.remove(cu);
                }
            }
        }
        out
    }

    /// A review ended; a failed one keeps its causes for the next attempt.
    pub(crate) fn review_ends(&mut self, causes: Vec<Cause>, error: Option<String>) {
        self.phase = Phase::Stable;
        self.reviews += 1;
        // A review the failure back-off scheduled (set while it ran) keeps its time.
        self.next_review_at = self
            .next_review_at
            .max(SystemTime::now())
            .min(SystemTime::now() + self.stable_interval());
        if error.is_some() {
            let mut kept = causes;
            kept.append(&mut self.causes);
            self.causes = kept;
        }
        self.last_error = error;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn schedule() -> Schedule {
        Schedule::new(Settings {
            horizon: 10.0,
            time_unit: Duration::from_secs(1),
            explore_timeout: None,
            explore_threads: 1,
            review_spacing: Duration::from_millis(100),
            history_limit: 0,
        })
    }

    #[test]
    fn a_kept_crash_is_repaired_by_the_first_change_set_satisfying_a_target_it_left_unsatisfied() {
        let mut s = schedule();
        let crash = Cause::CuCrashed {
            cu: "cu-1".into(),
            also: Vec::new(),
        };
        let (qa, qb): (Qid, Qid) = ("qa".into(), "qb".into());
        s.keep_crashes(std::slice::from_ref(&crash), std::slice::from_ref(&qa));
        // A change set that leaves qa unsatisfied (qb too, now) is not its repair; kept
        // again, it still waits for qa only.
        let both = [qa.clone(), qb.clone()];
        let unrepaired = s.unrepaired(std::slice::from_ref(&crash), &both);
        assert_eq!(unrepaired, std::slice::from_ref(&crash));
        s.keep_crashes(&unrepaired, &both);
        assert_eq!(
            s.unrepaired(std::slice::from_ref(&crash), &[qa]),
            std::slice::from_ref(&crash)
        );
        // qa satisfied (qb still not): repaired, and forgotten.
        assert!(s.unrepaired(std::slice::from_ref(&crash), &[qb]).is_empty());
        assert!(s.kept.is_empty());
        // A crash never kept is repaired by the change set of its own review.
        assert!(s.unrepaired(std::slice::from_ref(&crash), &[]).is_empty());
    }

    #[test]
    fn crashes_soon_after_a_review_wait_for_the_spacing_other_perturbations_do_not() {
        let mut s = schedule();
        // A crash after a calm period: a review at once.
        s.perturbed(&Perturbation::CuCrashed { cu: "cu-1".into() });
        assert_eq!(s.wait(), Duration::ZERO);
        assert!(s.due().0);
        let (causes, _) = s.review_starts();
        assert_eq!(causes.len(), 1);
        s.review_ends(causes, None);
        // Crashes right after it (an hour's spacing here, so that no clock can make this
        // test wrong): held back, shown as pending, then one review for all of them.
        s.settings.review_spacing = Duration::from_secs(3600);
        for cu in ["cu-2", "cu-3", "cu-4"] {
            s.perturbed(&Perturbation::CuCrashed { cu: cu.into() });
        }
        assert!(!s.due().0, "a crash storm is coalesced");
        assert!(s.status().review_pending);
        assert!(s.wait() > Duration::ZERO);
        // The stable interval still bounds the wait.
        assert!(s.wait() <= Duration::from_secs(10));
        // Once the spacing has passed since the last review started:
        s.last_start = Instant::now().checked_sub(Duration::from_secs(3601));
        assert_eq!(s.wait(), Duration::ZERO);
        assert!(s.due().0);
        let (causes, _) = s.review_starts();
        assert_eq!(causes.len(), 3);
        assert_eq!(s.status().crashes, 4);
        s.review_ends(causes, None);
        // A target added right after a review is not held back.
        s.perturbed(&Perturbation::TargetAdded { target: "q".into() });
        assert_eq!(s.wait(), Duration::ZERO);
        assert!(s.due().0);
    }

    #[test]
    fn failures_in_a_row_back_off_up_to_the_stable_interval() {
        let mut s = schedule();
        let waits: Vec<Duration> = (0..10)
            .map(|_| {
                s.next_review_at = SystemTime::now() + Duration::from_secs(3600);
                s.failed("cu-1".into());
                s.wait()
            })
            .collect();
        assert!(!s.urgent, "a failure is not urgent: it waits");
        // About 100, 200, 400 ms, ..., then the stable interval (10 s).
        for (k, wait) in waits.iter().enumerate() {
            let expected = (FIRST_RETRY * (1 << k)).min(Duration::from_secs(10));
            assert!(
                *wait <= expected && *wait + Duration::from_millis(50) >= expected,
                "failure {k}: {wait:?}, expected {expected:?}"
            );
        }
        // An applied change set starts the count again.
        s.applied();
        s.next_review_at = SystemTime::now() + Duration::from_secs(3600);
        s.failed("cu-2".into());
        assert!(s.wait() <= FIRST_RETRY);
        let (causes, _) = s.review_starts();
        assert_eq!(causes.len(), 11, "every failed CU is a cause");
    }

    /// The cycle the life-cycle loop runs: a review starts when due, its change set fails,
    /// it ends. The waits double although each review starts after the time it was due.
    #[test]
    fn failed_reviews_in_a_row_wait_longer_and_longer() {
        let mut s = schedule();
        for k in 0..6 {
            s.next_review_at = SystemTime::now() - Duration::from_millis(5);
            assert!(s.due().0, "round {k}: due");
            let (causes, _) = s.review_starts();
            s.failed(format!("cu-{k}").into());
            s.review_ends(causes, None);
            let expected = FIRST_RETRY * (1 << k);
            let wait = s.wait();
            assert!(
                wait <= expected && wait + Duration::from_millis(50) >= expected,
                "round {k}: waits {wait:?}, expected {expected:?}"
            );
        }
    }

    #[test]
    fn a_check_is_a_pending_review_until_it_is_decided() {
        let mut s = schedule();
        s.perturbed(&Perturbation::Registered {
            transformations: vec!["t".into()],
        });
        assert!(s.status().review_pending);
        assert_eq!(s.wait(), Duration::ZERO);
        let (due, check) = s.due();
        assert_eq!((due, check), (false, Some(1)));
        // Still pending while the check runs; a registration arriving meanwhile is checked
        // again after the first check found the environment valid.
        assert!(s.status().review_pending);
        s.perturbed(&Perturbation::Deregistered {
            transformation: "t".into(),
        });
        s.checked(1);
        assert!(s.status().review_pending);
        assert_eq!(s.due(), (false, Some(2)));
        s.checked(2);
        assert!(!s.status().review_pending);
        assert_eq!(s.due(), (false, None));
        // A review answers every check.
        s.perturbed(&Perturbation::Registered {
            transformations: vec![],
        });
        s.review_starts();
        assert_eq!(s.due().1, None);
    }
}
