//! Constraint networks and their algebraic closure (issue 6, item 2): queue-based path
//! consistency (seed Algorithm 1), and exact consistency by backtracking over base relations
//! with path consistency at each node.

use crate::relation::Relation;

/// A network of RCC-8 constraints over variables `0..n`: the relation of every ordered pair,
/// kept converse-symmetric (`rel(j, i) = rel(i, j)⁻¹`), EQ on the diagonal.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Network {
    n: usize,
    rel: Vec<Relation>,
}

/// The closure found an empty relation: no scenario exists.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("inconsistent: no relation is possible between {0} and {1}")]
pub struct Inconsistent(pub usize, pub usize);

impl Network {
    /// `n` variables, every pair universal.
    pub fn new(n: usize) -> Self {
        let mut rel = vec![Relation::UNIVERSAL; n * n];
        for i in 0..n {
            rel[i * n + i] = Relation::EQ;
        }
        Self { n, rel }
    }

    /// The number of variables.
    pub fn len(&self) -> usize {
        self.n
    }

    /// Whether the network has no variables.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// The relation between `i` and `j`.
    pub fn get(&self, i: usize, j: usize) -> Relation {
        self.rel[i * self.n + j]
    }

    /// Sets the relation between `i` and `j` (and its converse between `j` and `i`).
    pub fn set(&mut self, i: usize, j: usize, r: Relation) {
        self.rel[i * self.n + j] = r;
        self.rel[j * self.n + i] = r.converse();
    }

    /// Intersects the relation between `i` and `j` with `r`; returns the result.
    pub fn constrain(&mut self, i: usize, j: usize, r: Relation) -> Relation {
        let r = self.get(i, j).and(r);
        self.set(i, j, r);
        r
    }

    /// The algebraic closure (seed Algorithm 1): refines every relation by composition along
    /// every path of length two until nothing changes. `Err` when a relation becomes empty
    /// (the network is then left partly refined).
    pub fn algebraic_closure(&mut self) -> Result<(), Inconsistent> {
        let edges: Vec<(usize, usize)> = (0..self.n)
            .flat_map(|i| (i + 1..self.n).map(move |j| (i, j)))
            .filter(|(i, j)| self.get(*i, *j) != Relation::UNIVERSAL)
            .collect();
        self.close_from(&edges)
    }

    /// Path consistency from the edges that changed (the incremental closure of Ch. 3.4.2:
    /// after adding constraints to a closed network, only paths through them can refine).
    pub fn close_from(&mut self, changed: &[(usize, usize)]) -> Result<(), Inconsistent> {
        let n = self.n;
        for i in 0..n {
            if self.get(i, i).is_empty() || !self.get(i, i).contains(Relation::EQ) {
                return Err(Inconsistent(i, i));
            }
        }
        let mut queued = vec![false; n * n];
        let mut queue: Vec<(usize, usize)> = Vec::with_capacity(changed.len());
        for &(i, j) in changed {
            let (i, j) = if i < j { (i, j) } else { (j, i) };
            if i != j && !queued[i * n + j] {
                if self.get(i, j).is_empty() {
                    return Err(Inconsistent(i, j));
                }
                queued[i * n + j] = true;
                queue.push((i, j));
            }
        }
        while let Some((i, j)) = queue.pop() {
            queued[i * n + j] = false;
            let rij = self.get(i, j);
            for k in 0..n {
                if k == i || k == j {
                    continue;
                }
                // (i, k) through j.
                let rik = self.get(i, k);
                let refined = rik.and(rij.compose(self.get(j, k)));
                if refined != rik {
                    if refined.is_empty() {
                        self.set(i, k, refined);
                        return Err(Inconsistent(i, k));
                    }
                    self.set(i, k, refined);
                    let (a, b) = if i < k { (i, k) } else { (k, i) };
                    if !queued[a * n + b] {
                        queued[a * n + b] = true;
                        queue.push((a, b));
                    }
                }
                // (k, j) through i.
                let rkj = self.get(k, j);
                let refined = rkj.and(self.get(k, i).compose(rij));
                if refined != rkj {
                    if refined.is_empty() {
                        self.set(k, j, refined);
                        return Err(Inconsistent(k, j));
                    }
                    self.set(k, j, refined);
                    let (a, b) = if k < j { (k, j) } else { (j, k) };
                    if !queued[a * n + b] {
                        queued[a * n + b] = true;
                        queue.push((a, b));
                    }
                }
            }
        }
        Ok(())
    }

    /// Exact consistency: whether some scenario (one base relation per pair) satisfies every
    /// constraint. Backtracking: close, pick the undecided pair with the fewest relations, try
    /// each of its base relations. On success the network is left as a consistent scenario
    /// (for RCC-8, an atomic path-consistent network is consistent: Renz and Nebel 1999).
    pub fn solve(&mut self) -> bool {
        if self.algebraic_closure().is_err() {
            return false;
        }
        self.search()
    }

    fn search(&mut self) -> bool {
        let mut pick: Option<(usize, usize, u32)> = None;
        for i in 0..self.n {
            for j in i + 1..self.n {
                let k = self.get(i, j).len();
                if k > 1 && pick.is_none_or(|(_, _, best)| k < best) {
                    pick = Some((i, j, k));
                }
            }
        }
        let Some((i, j, _)) = pick else {
            return true;
        };
        for b in self.get(i, j).bases() {
            let mut next = self.clone();
            next.set(i, j, b);
            if next.close_from(&[(i, j)]).is_ok() && next.search() {
                *self = next;
                return true;
            }
        }
        false
    }
}
