//! GQR's CSP file format (contract `rcc8.md`), so GQR's published instances and generators work
//! unchanged:
//! ```text
//! 29 # a comment: the first number is the highest variable index (n - 1)
//!  0  1 ( PO NTPPI )
//!  1  2 ( DC )
//! .
//! ```
//! One constraint per line, `i j ( R ... )`; unlisted pairs are universal; `i j` and `j i` are
//! intersected (after converting one); `.` ends an instance; a file may hold several.

use crate::network::Network;
use crate::relation::Relation;

/// The largest number of variables accepted in an instance (the matrix is n² bytes).
pub const MAX_VARIABLES: usize = 4_096;

/// The most matrix cells (bytes) all the instances of one file may take together: four
/// instances of [`MAX_VARIABLES`], so that a few bytes of headers cannot ask for gigabytes.
pub const MAX_CELLS: usize = 4 * MAX_VARIABLES * MAX_VARIABLES;

/// A syntax error, located.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("line {line}, column {column}: {message}")]
pub struct ParseError {
    /// 1-based line.
    pub line: usize,
    /// 1-based column (in characters).
    pub column: usize,
    /// What is wrong.
    pub message: String,
}

/// Reads every instance of a file. An instance without its closing `.` at the end of the file
/// is accepted (GQR's generators end files that way too).
pub fn parse(text: &str) -> Result<Vec<Network>, ParseError> {
    let mut out = Vec::new();
    let mut current: Option<Network> = None;
    let mut cells = 0usize;
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let content = raw.split('#').next().unwrap_or("");
        let trimmed = content.trim();
        if trimmed.is_empty() {
            continue;
        }
        let column_of = |needle: &str| raw.find(needle).map_or(1, |b| raw[..b].chars().count() + 1);
        let err = |column: usize, message: String| ParseError {
            line,
            column,
            message,
        };
        if trimmed == "." {
            match current.take() {
                Some(n) => out.push(n),
                None => {
                    return Err(err(
                        column_of("."),
                        "'.' before an instance's header".into(),
                    ));
                }
            }
            continue;
        }
        let Some(network) = current.as_mut() else {
            // The header: the highest variable index.
            let max: usize = trimmed.parse().map_err(|_| {
                err(
                    column_of(trimmed),
                    format!("expected the highest variable index, found '{trimmed}'"),
                )
            })?;
            if max >= MAX_VARIABLES {
                return Err(err(
                    column_of(trimmed),
                    format!(
                        "the highest variable index {max} is beyond the {} accepted ({MAX_VARIABLES} variables)",
                        MAX_VARIABLES - 1
                    ),
                ));
            }
            cells += (max + 1) * (max + 1);
            if cells > MAX_CELLS {
                return Err(err(
                    column_of(trimmed),
                    format!(
                        "the instances of this file would need more than {MAX_CELLS} matrix cells \
                         together (n² per instance of n variables)"
                    ),
                ));
            }
            current = Some(Network::new(max + 1));
            continue;
        };
        // `i j ( R ... )`
        let open = trimmed
            .find('(')
            .ok_or_else(|| err(column_of(trimmed), "expected 'i j ( R ... )'".into()))?;
        let close = trimmed
            .rfind(')')
            .filter(|c| *c > open)
            .ok_or_else(|| err(raw.chars().count() + 1, "missing ')'".into()))?;
        if !trimmed[close + 1..].trim().is_empty() {
            return Err(err(
                column_of(trimmed[close + 1..].trim()),
                "text after ')'".into(),
            ));
        }
        let vars: Vec<&str> = trimmed[..open].split_whitespace().collect();
        let [a, b] = vars.as_slice() else {
            return Err(err(
                column_of(trimmed),
                "expected two variable indices before '('".into(),
            ));
        };
        let index = |v: &str| -> Result<usize, ParseError> {
            let i: usize = v
                .parse()
                .map_err(|_| err(column_of(v), format!("'{v}' is not a variable index")))?;
            if i >= network.len() {
                return Err(err(
                    column_of(v),
                    format!("variable {i} beyond the header's {}", network.len() - 1),
                ));
            }
            Ok(i)
        };
        let (i, j) = (index(a)?, index(b)?);
        let mut r = Relation::EMPTY;
        let mut names = trimmed[open + 1..close].split_whitespace().peekable();
        while let Some(name) = names.next() {
            // `TPP ^-1` is read as one name too.
            let joined;
            let name = if names.peek() == Some(&"^-1") {
                names.next();
                joined = format!("{name}^-1");
                joined.as_str()
            } else {
                name
            };
            r = r.or(Relation::from_name(name).ok_or_else(|| {
                err(
                    column_of(name),
                    format!("'{name}' is not an RCC-8 relation"),
                )
            })?);
        }
        network.constrain(i, j, r);
    }
    if let Some(n) = current {
        out.push(n);
    }
    Ok(out)
}

/// Writes a network in the same format: the header, then every pair `i < j` whose relation is
/// not universal, in order, then `.`. A variable's relation to itself is written too when it
/// is not `EQ` (an instance that constrains `i i` without `EQ` is inconsistent, and reads back
/// so).
pub fn write(network: &Network, out: &mut impl std::fmt::Write) -> std::fmt::Result {
    writeln!(out, "{}", network.len().saturating_sub(1))?;
    for i in 0..network.len() {
        for j in i..network.len() {
            let r = network.get(i, j);
            let implied = if i == j {
                Relation::EQ
            } else {
                Relation::UNIVERSAL
            };
            if r != implied {
                writeln!(out, "{i} {j} {r}")?;
            }
        }
    }
    writeln!(out, ".")
}
