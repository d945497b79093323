//! RCC-8 relations as 8-bit sets (issue 6, item 1). The composition of the base relations is
//! stated once ([`BASE_COMPOSITION`], the table of Randell, Cui and Cohn); the composition and
//! converse of every one of the 256 sets are precomputed from it at compile time.

use std::fmt;

/// A set of RCC-8 base relations (a disjunction). Bit i is the base relation of index i in
/// [`Relation::BASE`]: DC, EC, PO, EQ, TPP, NTPP, TPPI, NTPPI.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct Relation(pub u8);

impl Relation {
    /// Disconnected.
    pub const DC: Self = Self(1 << 0);
    /// Externally connected.
    pub const EC: Self = Self(1 << 1);
    /// Partially overlapping.
    pub const PO: Self = Self(1 << 2);
    /// Equal.
    pub const EQ: Self = Self(1 << 3);
    /// Tangential proper part.
    pub const TPP: Self = Self(1 << 4);
    /// Non-tangential proper part.
    pub const NTPP: Self = Self(1 << 5);
    /// Inverse of TPP.
    pub const TPPI: Self = Self(1 << 6);
    /// Inverse of NTPP.
    pub const NTPPI: Self = Self(1 << 7);
    /// The empty relation (no base relation is possible: inconsistency).
    pub const EMPTY: Self = Self(0);
    /// The universal relation (nothing is known).
    pub const UNIVERSAL: Self = Self(0xff);
    /// The base relations in bit order.
    pub const BASE: [Self; 8] = [
        Self::DC,
        Self::EC,
        Self::PO,
        Self::EQ,
        Self::TPP,
        Self::NTPP,
        Self::TPPI,
        Self::NTPPI,
    ];
    /// Their canonical names (`rcc8.md`), in bit order.
    pub const NAMES: [&'static str; 8] = ["DC", "EC", "PO", "EQ", "TPP", "NTPP", "TPPI", "NTPPI"];

    /// Whether no base relation is left.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// Whether this is a single base relation.
    pub const fn is_base(self) -> bool {
        self.0.count_ones() == 1
    }

    /// The number of base relations in the set.
    pub const fn len(self) -> u32 {
        self.0.count_ones()
    }

    /// Whether `other` is a subset.
    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0
    }

    /// Intersection.
    pub const fn and(self, other: Self) -> Self {
        Self(self.0 & other.0)
    }

    /// Union.
    pub const fn or(self, other: Self) -> Self {
        Self(self.0 | other.0)
    }

    /// The converse: `R(a, b)` iff `converse(R)(b, a)`.
    pub const fn converse(self) -> Self {
        Self(CONVERSE[self.0 as usize])
    }

    /// Weak composition: the relations possible between a and c when `self(a, b)` and
    /// `other(b, c)`.
    pub fn compose(self, other: Self) -> Self {
        Self(COMPOSITION[self.0 as usize * 256 + other.0 as usize])
    }

    /// The base relations of the set.
    pub fn bases(self) -> impl Iterator<Item = Self> {
        Self::BASE.into_iter().filter(move |b| self.contains(*b))
    }

    /// Reads a base relation's name: the canonical spellings, `TPPi`, `NTPPi`, `TPP^-1`,
    /// `NTPP^-1`, and the seed's `NTTP` with its inverse in the same forms, `NTTP^-1`, `NTTPi`
    /// and `NTTPI` (`rcc8.md`).
    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name {
            "DC" => Self::DC,
            "EC" => Self::EC,
            "PO" => Self::PO,
            "EQ" => Self::EQ,
            "TPP" => Self::TPP,
            "NTPP" | "NTTP" => Self::NTPP,
            "TPPI" | "TPPi" | "TPP^-1" => Self::TPPI,
            "NTPPI" | "NTPPi" | "NTPP^-1" | "NTTPI" | "NTTPi" | "NTTP^-1" => Self::NTPPI,
            _ => return None,
        })
    }
}

/// `( DC EC )`: names separated by spaces inside parentheses, in canonical order.
impl fmt::Display for Relation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("(")?;
        for (i, name) in Self::NAMES.iter().enumerate() {
            if self.0 & (1 << i) != 0 {
                write!(f, " {name}")?;
            }
        }
        f.write_str(" )")
    }
}

const DC: u8 = 1;
const EC: u8 = 2;
const PO: u8 = 4;
const EQ: u8 = 8;
const TPP: u8 = 16;
const NTPP: u8 = 32;
const TPPI: u8 = 64;
const NTPPI: u8 = 128;
const ALL: u8 = 0xff;

/// The composition of the base relations: `BASE_COMPOSITION[i][j]` is `BASE[i] ∘ BASE[j]`
/// (Randell, Cui and Cohn 1992; the seed's Table 3.1 cites the same). Rows and columns in
/// bit order: DC, EC, PO, EQ, TPP, NTPP, TPPI, NTPPI.
pub const BASE_COMPOSITION: [[u8; 8]; 8] = [
    // DC ∘ …
    [
        ALL,
        DC | EC | PO | TPP | NTPP,
        DC | EC | PO | TPP | NTPP,
        DC,
        DC | EC | PO | TPP | NTPP,
        DC | EC | PO | TPP | NTPP,
        DC,
        DC,
    ],
    // EC ∘ …
    [
        DC | EC | PO | TPPI | NTPPI,
        DC | EC | PO | EQ | TPP | TPPI,
        DC | EC | PO | TPP | NTPP,
        EC,
        EC | PO | TPP | NTPP,
        PO | TPP | NTPP,
        DC | EC,
        DC,
    ],
    // PO ∘ …
    [
        DC | EC | PO | TPPI | NTPPI,
        DC | EC | PO | TPPI | NTPPI,
        ALL,
        PO,
        PO | TPP | NTPP,
        PO | TPP | NTPP,
        DC | EC | PO | TPPI | NTPPI,
        DC | EC | PO | TPPI | NTPPI,
    ],
    // EQ ∘ …
    [DC, EC, PO, EQ, TPP, NTPP, TPPI, NTPPI],
    // TPP ∘ …
    [
        DC,
        DC | EC,
        DC | EC | PO | TPP | NTPP,
        TPP,
        TPP | NTPP,
        NTPP,
        DC | EC | PO | EQ | TPP | TPPI,
        DC | EC | PO | TPPI | NTPPI,
    ],
    // NTPP ∘ …
    [
        DC,
        DC,
        DC | EC | PO | TPP | NTPP,
        NTPP,
        NTPP,
        NTPP,
        DC | EC | PO | TPP | NTPP,
        ALL,
    ],
    // TPPI ∘ …
    [
        DC | EC | PO | TPPI | NTPPI,
        EC | PO | TPPI | NTPPI,
        PO | TPPI | NTPPI,
        TPPI,
        PO | EQ | TPP | TPPI,
        PO | TPP | NTPP,
        TPPI | NTPPI,
        NTPPI,
    ],
    // NTPPI ∘ …
    [
        DC | EC | PO | TPPI | NTPPI,
        PO | TPPI | NTPPI,
        PO | TPPI | NTPPI,
        NTPPI,
        PO | TPPI | NTPPI,
        PO | EQ | TPP | NTPP | TPPI | NTPPI,
        NTPPI,
        NTPPI,
    ],
];

/// The converse of each base relation, in bit order.
const BASE_CONVERSE: [u8; 8] = [DC, EC, PO, EQ, TPPI, NTPPI, TPP, NTPP];

/// The converse of every set.
static CONVERSE: [u8; 256] = {
    let mut t = [0u8; 256];
    let mut r = 0;
    while r < 256 {
        let mut out = 0u8;
        let mut i = 0;
        while i < 8 {
            if r & (1 << i) != 0 {
                out |= BASE_CONVERSE[i];
            }
            i += 1;
        }
        t[r] = out;
        r += 1;
    }
    t
};

/// The 256 × 256 composition table, row `a` at `a * 256`.
pub(crate) fn composition_table() -> &'static [u8] {
    &COMPOSITION
}

/// `BASE[i] ∘ s` for every base relation `i` and set `s`.
const ROWS: [[u8; 256]; 8] = {
    let mut t = [[0u8; 256]; 8];
    let mut i = 0;
    while i < 8 {
        let mut b = 0;
        while b < 256 {
            let mut out = 0u8;
            let mut j = 0;
            while j < 8 {
                if b & (1 << j) != 0 {
                    out |= BASE_COMPOSITION[i][j];
                }
                j += 1;
            }
            t[i][b] = out;
            b += 1;
        }
        i += 1;
    }
    t
};

/// The composition of every pair of sets, the union of the compositions of their base
/// relations (64 KiB, built on first use: too long for compile-time evaluation).
static COMPOSITION: std::sync::LazyLock<Box<[u8]>> = std::sync::LazyLock::new(|| {
    let mut t = vec![0u8; 65536];
    for a in 0..256usize {
        for b in 0..256usize {
            let mut out = 0u8;
            for (i, row) in ROWS.iter().enumerate() {
                if a & (1 << i) != 0 {
                    out |= row[b];
                }
            }
            t[a * 256 + b] = out;
        }
    }
    t.into_boxed_slice()
});

#[cfg(test)]
mod tests {
    use super::Relation;

    /// Every spelling `rcc8.md` accepts, the seed's `NTTP` and its inverse included.
    #[test]
    fn names_and_their_aliases() {
        for (names, relation) in [
            (&["NTPP", "NTTP"][..], Relation::NTPP),
            (&["TPPI", "TPPi", "TPP^-1"], Relation::TPPI),
            (
                &["NTPPI", "NTPPi", "NTPP^-1", "NTTPI", "NTTPi", "NTTP^-1"],
                Relation::NTPPI,
            ),
        ] {
            for name in names {
                assert_eq!(Relation::from_name(name), Some(relation), "{name}");
            }
        }
        for name in Relation::NAMES {
            assert!(Relation::from_name(name).is_some(), "{name}");
        }
        for bad in ["ntpp", "NTTP^-2", "NTP", "TTP^-1", ""] {
            assert_eq!(Relation::from_name(bad), None, "{bad}");
        }
    }
}
