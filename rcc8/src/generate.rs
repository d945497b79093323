//! Seeded random networks for tests, benchmarks and experiments: Renz and Nebel's model
//! A(n, d, l) (the instances of the seed's Ch. 3.5.3), and consistent scenarios realised by
//! discs in the plane (ground truth: every relation is the one two actual regions have).

use crate::network::Network;
use crate::relation::Relation;

/// SplitMix64: a small seeded generator, so instances are reproducible without a dependency.
#[derive(Debug, Clone)]
pub struct Rng(pub u64);

impl Rng {
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64 <= p
    }

    /// A number in `0..m` (`m > 0`).
    pub fn below(&mut self, m: u64) -> u64 {
        self.next_u64() % m
    }
}

/// A non-empty relation holding each base relation with probability `l / 8` (so `l` is the
/// expected label size; an empty draw is drawn again).
pub fn relation(rng: &mut Rng, l: f64) -> Relation {
    loop {
        let mut r = 0u8;
        for i in 0..8 {
            if rng.chance(l / 8.0) {
                r |= 1 << i;
            }
        }
        if r != 0 {
            return Relation(r);
        }
    }
}

/// An instance of model A(n, d, l): each of the n(n-1)/2 pairs is constrained with
/// probability d / (n - 1), so the average degree is d, by [`relation`]`(l)`.
pub fn model_a(rng: &mut Rng, n: usize, d: f64, l: f64) -> Network {
    let mut net = Network::new(n);
    let p = if n > 1 { d / (n - 1) as f64 } else { 0.0 };
    for i in 0..n {
        for j in i + 1..n {
            if rng.chance(p) {
                net.set(i, j, relation(rng, l));
            }
        }
    }
    net
}

/// A closed disc with integer centre and radius: small grids make tangencies (EC, TPP, EQ)
/// common.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Disc {
    /// Centre.
    pub x: i64,
    /// Centre.
    pub y: i64,
    /// Radius (> 0).
    pub r: i64,
}

impl Disc {
    /// A random disc: centre in `0..grid`² and radius in `1..=max_r`.
    pub fn random(rng: &mut Rng, grid: u64, max_r: u64) -> Self {
        Self {
            x: rng.below(grid) as i64,
            y: rng.below(grid) as i64,
            r: 1 + rng.below(max_r) as i64,
        }
    }

    /// The RCC-8 base relation between two discs, computed exactly.
    pub fn relation(self, other: Self) -> Relation {
        let dist2 = (self.x - other.x).pow(2) + (self.y - other.y).pow(2);
        let sum2 = (self.r + other.r).pow(2);
        let diff2 = (self.r - other.r).pow(2);
        if dist2 == 0 && self.r == other.r {
            Relation::EQ
        } else if dist2 > sum2 {
            Relation::DC
        } else if dist2 == sum2 {
            Relation::EC
        } else if dist2 > diff2 {
            Relation::PO
        } else if self.r < other.r {
            if dist2 == diff2 {
                Relation::TPP
            } else {
                Relation::NTPP
            }
        } else if dist2 == diff2 {
            Relation::TPPI
        } else {
            Relation::NTPPI
        }
    }
}

/// The scenario (one base relation per pair) of the given discs.
pub fn scenario(discs: &[Disc]) -> Network {
    let mut net = Network::new(discs.len());
    for (i, a) in discs.iter().enumerate() {
        for (j, b) in discs.iter().enumerate().skip(i + 1) {
            net.set(i, j, a.relation(*b));
        }
    }
    net
}

/// `n` random discs on a 40 × 40 grid with radii up to 12.
pub fn discs(rng: &mut Rng, n: usize) -> Vec<Disc> {
    (0..n).map(|_| Disc::random(rng, 40, 12)).collect()
}
