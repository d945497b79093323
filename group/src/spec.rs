//! A group's definition as clients post it (contract `groups.md`, `POST /groups`), its
//! validation, and the grounding of its symbols in targets.

use std::collections::{BTreeMap, BTreeSet};

use dyknow_mstl::{CompileError, Domains, Formula, Symbol, ground_atoms, ground_symbols, parse};
use serde::{Deserialize, Serialize};

use crate::sync::Policy;

/// `POST /groups`'s body.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroupSpec {
    /// The label (`g-N` when absent).
    #[serde(default)]
    pub label: Option<String>,
    /// Where verdicts are published (`/dyknow/verdicts/<label>` when absent).
    #[serde(default)]
    pub result_channel: Option<String>,
    /// The formulas (MSTL, `mstl.md`).
    #[serde(default)]
    pub formulas: Vec<String>,
    /// Named domains for quantifiers.
    #[serde(default)]
    pub domains: Domains,
    /// Landmark regions.
    #[serde(default)]
    pub landmarks: Vec<String>,
    /// Static regions.
    #[serde(default, rename = "static")]
    pub static_regions: Vec<String>,
    /// Symbol → the tag its target asks for.
    #[serde(default)]
    pub grounding: BTreeMap<String, Grounding>,
    /// The synchronisation policy.
    #[serde(default)]
    pub sync: Policy,
    /// Start at once.
    #[serde(default)]
    pub start: bool,
}

/// The tag a symbol's target asks for, instead of the symbol itself: `{"tag": "..."}` or
/// `{"description": "<IRI>"}`.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(untagged, try_from = "GroundingFields")]
pub enum Grounding {
    /// A tag value (`dyknow:hasValue`).
    Tag {
        /// The value.
        tag: String,
    },
    /// A tag description concept (`dyknow:hasTagDescription`).
    Description {
        /// The concept's IRI.
        description: String,
    },
}

/// A grounding as written: read field by field, so that a wrong one is refused with what a
/// grounding is (an untagged enum said only "data did not match any variant").
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct GroundingFields {
    tag: Option<String>,
    description: Option<String>,
}

impl TryFrom<GroundingFields> for Grounding {
    type Error = String;

    fn try_from(fields: GroundingFields) -> Result<Self, String> {
        match (fields.tag, fields.description) {
            (Some(tag), None) => Ok(Self::Tag { tag }),
            (None, Some(description)) => Ok(Self::Description { description }),
            (tag, _) => Err(format!(
                "a symbol's grounding is {{\"tag\": \"<value>\"}} or {{\"description\": \"<IRI>\"}}, \
                 not {}",
                if tag.is_some() { "both" } else { "neither" }
            )),
        }
    }
}

/// Why a group or formula is refused (nothing is created).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SpecError {
    /// A formula does not parse (400).
    #[error("formula {index}: column {column}: {message}")]
    Syntax {
        /// The formula's position.
        index: usize,
        /// 1-based column.
        column: usize,
        /// What is wrong.
        message: String,
    },
    /// A formula cannot be grounded: an unknown domain, a bad constant (422).
    #[error("formula {index}: column {column}: {message}")]
    Grounding {
        /// The formula's position.
        index: usize,
        /// 1-based column.
        column: usize,
        /// What is wrong.
        message: String,
    },
    /// Anything else about the group: a bad label, channel, grounding or policy (422).
    #[error("{0}")]
    Invalid(String),
}

/// A formula parsed and grounded.
#[derive(Debug, Clone)]
pub struct Grounded {
    /// The formula.
    pub formula: Formula,
    /// Its ground symbols.
    pub symbols: BTreeSet<Symbol>,
}

/// The most ground atoms a formula may expand to. Quantifiers multiply: `forall x in D:
/// forall y in D: forall z in D: p(x,y,z)` over 200 constants is 8 million atoms, and a 2 KB
/// group definition of it took 2.6 GB and a minute of both cores before it was bounded.
pub const MAX_GROUND_ATOMS: u64 = 10_000;

/// Parses and grounds formula `index` over `domains`; one that expands to more than
/// [`MAX_GROUND_ATOMS`] atoms is refused before it is expanded.
pub fn ground(index: usize, text: &str, domains: &Domains) -> Result<Grounded, SpecError> {
    let formula = parse(text).map_err(|e| SpecError::Syntax {
        index,
        column: e.column,
        message: e.message.clone(),
    })?;
    let atoms = ground_atoms(&formula, domains);
    if atoms > MAX_GROUND_ATOMS {
        return Err(SpecError::Grounding {
            index,
            column: 1,
            message: format!(
                "the formula grounds to {atoms} atoms over its domains; at most \
                 {MAX_GROUND_ATOMS} are taken"
            ),
        });
    }
    let symbols = ground_symbols(&formula, domains).map_err(|e| match &e {
        // The compiler's words are `dyknow check`'s (a trace header): a group declares its
        // domains in its body, or with `dyknow group create --domain`.
        CompileError::UnknownDomain(d) => SpecError::Grounding {
            index,
            column: domain_column(text, d),
            message: format!(
                "unknown domain '{d}' (declare it in the group's \"domains\", e.g. \
                 {{\"{d}\": [\"a\", \"b\"]}}, or with `dyknow group create --domain {d}=a,b`)"
            ),
        },
        _ => SpecError::Grounding {
            index,
            column: 1,
            message: e.to_string(),
        },
    })?;
    // Each symbol becomes a target labelled `symbol:<key>` whose tag is the key: a spec the
    // store must take (at most 4,096 bytes of label, nothing XML cannot carry), or every
    // group's targets would fail to be posted with it.
    for symbol in &symbols {
        let key = symbol.key();
        let why = if key.len() > MAX_SYMBOL_BYTES {
            Some(format!(
                "the ground symbol {}… is {} bytes long; a symbol names a target, at most \
                 {MAX_SYMBOL_BYTES} bytes",
                key.chars().take(40).collect::<String>(),
                key.len()
            ))
        } else if !key.chars().all(xml_char) {
            Some(format!(
                "the ground symbol {key:?} holds a control character or a non-character, \
                 which no target's tag can carry"
            ))
        } else {
            None
        };
        if let Some(message) = why {
            return Err(SpecError::Grounding {
                index,
                column: 1,
                message,
            });
        }
    }
    Ok(Grounded { formula, symbols })
}

/// The most bytes of a ground symbol: its target's label, `symbol:<key>`, is at most the
/// store's 4,096.
pub const MAX_SYMBOL_BYTES: usize = 4096 - "symbol:".len();

/// Whether a tag or label may hold `c`: no control character and neither U+FFFE nor U+FFFF
/// (XML 1.0, in which the model is exported, cannot carry them; the store refuses them).
fn xml_char(c: char) -> bool {
    !c.is_control() && c != '\u{FFFE}' && c != '\u{FFFF}'
}

/// The 1-based column (in characters) of domain `d` after `in` in `text`.
fn domain_column(text: &str, d: &str) -> usize {
    word_columns(text, d)
        .find(|&i| {
            let before: String = text.chars().take(i - 1).collect();
            before.trim_end().ends_with("in")
        })
        .unwrap_or(1)
}

/// The 1-based columns (in characters) where `name` is written as a whole word in `text`.
fn word_columns<'a>(text: &'a str, name: &'a str) -> impl Iterator<Item = usize> + 'a {
    let chars: Vec<char> = text.chars().collect();
    let name: Vec<char> = name.chars().collect();
    let word = |c: char| c.is_alphanumeric() || c == '_';
    (0..chars.len())
        .filter(move |&i| {
            !name.is_empty()
                && chars[i..].starts_with(&name)
                && (i == 0 || !word(chars[i - 1]))
                && chars.get(i + name.len()).is_none_or(|c| !word(*c))
        })
        .map(|i| i + 1)
}

/// Checks a label, channel or region name: 1 to 200 characters, none of them a control
/// character or U+FFFE, U+FFFF.
pub fn check_name(what: &str, name: &str) -> Result<(), SpecError> {
    if name.is_empty() || name.chars().count() > 200 || !name.chars().all(xml_char) {
        return Err(SpecError::Invalid(format!(
            "{what} must be 1 to 200 characters without control characters (nor U+FFFE, \
             U+FFFF): {name:?}"
        )));
    }
    Ok(())
}

/// Checks a group label: also no '/', and not `.` or `..` (it is a path segment, and clients
/// resolve those before they send a request: `/groups/..` becomes `/`).
pub fn check_label(label: &str) -> Result<(), SpecError> {
    check_name("label", label)?;
    if label.contains('/') {
        return Err(SpecError::Invalid(format!(
            "a group label cannot hold '/': {label:?}"
        )));
    }
    if label == "." || label == ".." {
        return Err(SpecError::Invalid(format!(
            "a group label cannot be {label:?} (URLs resolve it away)"
        )));
    }
    Ok(())
}

/// Checks what a spec declares besides its formulas.
pub fn validate(spec: &GroupSpec) -> Result<(), SpecError> {
    if let Some(l) = &spec.label {
        check_label(l)?;
    }
    if let Some(c) = &spec.result_channel {
        check_name("result_channel", c)?;
    }
    spec.sync.validate().map_err(SpecError::Invalid)?;
    for (name, constants) in &spec.domains {
        check_name("a domain name", name)?;
        for c in constants {
            check_name(&format!("a constant of domain {name}"), c)?;
            dyknow_mstl::check_constant(c)
                .map_err(|e| SpecError::Invalid(format!("domain {name}: {e}")))?;
        }
    }
    for r in spec.landmarks.iter().chain(&spec.static_regions) {
        check_name("a region", r)?;
        // A region no formula can name (a space, a comma, a bracket) is refused as a domain
        // constant is: it was taken, and nothing could ever refer to it (a user audit).
        dyknow_mstl::check_constant(r).map_err(|e| {
            SpecError::Invalid(format!(
                "landmarks and static regions are names formulas write: {e}"
            ))
        })?;
    }
    Ok(())
}

/// Checks the grounding entries once the formulas are grounded: an invalid one is refused
/// naming the first formula that has the symbol, at the column where the symbol's name is
/// written (else 1). Entries for symbols no formula has are left to the caller.
pub fn check_groundings(
    grounding: &BTreeMap<String, Grounding>,
    formulas: &[String],
    grounded: &[Grounded],
) -> Result<(), SpecError> {
    for (symbol, g) in grounding {
        let wrong = match g {
            // A value written as an IRI would name the target of that IRI as a description.
            Grounding::Tag { tag } if tag.starts_with('<') => Some(format!(
                "the grounding tag of {symbol}: {tag:?} begins with '<', as an IRI is written; \
                 a tag description IRI is given as {{\"description\": \"<IRI>\"}}, without \
                 the brackets"
            )),
            Grounding::Tag { tag } => check_name(&format!("the grounding tag of {symbol}"), tag)
                .err()
                .map(|e| e.to_string()),
            Grounding::Description { description } => {
                if !is_iri(description) {
                    Some(format!(
                        "the grounding of {symbol}: {description:?} is not an absolute IRI"
                    ))
                } else if description.len() + 2 > MAX_SYMBOL_BYTES {
                    Some(format!(
                        "the grounding of {symbol}: the IRI is {} bytes long; it names a \
                         target, at most {} bytes",
                        description.len(),
                        MAX_SYMBOL_BYTES - 2
                    ))
                } else {
                    None
                }
            }
        };
        let Some(message) = wrong else { continue };
        let Some(index) = grounded
            .iter()
            .position(|g| g.symbols.iter().any(|s| s.key() == *symbol))
        else {
            return Err(SpecError::Invalid(message));
        };
        return Err(SpecError::Grounding {
            index,
            column: symbol_column(&formulas[index], symbol),
            message,
        });
    }
    Ok(())
}

/// The 1-based column (in characters) where the name of `symbol` (`altitude` of
/// `altitude(uav1)`, `PO` of `PO(a,b)`) is first written as a whole word in `text`; 1 when it
/// is not found.
fn symbol_column(text: &str, symbol: &str) -> usize {
    let name = symbol.split('(').next().unwrap_or(symbol);
    word_columns(text, name).next().unwrap_or(1)
}

fn is_iri(s: &str) -> bool {
    let Some((scheme, rest)) = s.split_once(':') else {
        return false;
    };
    !rest.is_empty()
        && scheme
            .chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic())
        && scheme
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c))
        && !s.chars().any(|c| {
            c.is_whitespace()
                || "<>\"{}|\\^`".contains(c)
                // What no IRI holds (RFC 3987: controls, and U+FFFE, U+FFFF are no `ucschar`);
                // accepted, the group's target could not be written, and with it no other
                // group's (a code review).
                || c.is_control()
                || c == '\u{FFFE}'
                || c == '\u{FFFF}'
        })
}

/// The tag a symbol's target asks for.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub enum TargetTag {
    /// A tag value.
    Value(String),
    /// A tag description IRI.
    Description(String),
}

impl TargetTag {
    /// The target's label: `symbol:` followed by the tag value, or by the description IRI
    /// in angle brackets (`symbol:<urn:x:Foo>`), so that a value spelled as an IRI
    /// (`urn:x:Foo`) and the IRI never share a target (they did: the second group was fed the
    /// first one's stream). A tag value may not begin with `<` ([`check_groundings`]).
    pub fn label(&self) -> String {
        format!("symbol:{}", self.written())
    }

    /// The tag as the label writes it: the value, or `<IRI>`.
    fn written(&self) -> String {
        match self {
            Self::Value(v) => v.clone(),
            Self::Description(iri) => format!("<{iri}>"),
        }
    }

    /// The target's channel, chosen by the service: `/dyknow/symbols/<tag>` with characters
    /// other than letters, digits and `_-.,()` replaced by `_` and, when any was replaced (or
    /// for a description), a hash of the tag appended so distinct tags never share a channel.
    pub fn channel(&self) -> String {
        let (text, force) = match self {
            Self::Value(v) => (v.as_str(), false),
            Self::Description(iri) => (iri.rsplit(['#', '/']).next().unwrap_or("d"), true),
        };
        let clean: String = text
            .chars()
            .take(80)
            .map(|c| {
                if c.is_ascii_alphanumeric() || "_-.,()".contains(c) {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        let clean = if clean.is_empty() {
            "_".to_owned()
        } else {
            clean
        };
        let whole = self.written();
        if force || clean != whole {
            format!("/dyknow/symbols/{clean}-{:08x}", fnv(&whole) as u32)
        } else {
            format!("/dyknow/symbols/{clean}")
        }
    }
}

fn fnv(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// The tag of `symbol`'s target: the group's grounding if it names the symbol; for a spatial
/// symbol without one, the relation itself if some transformation offers it
/// (`has_out_tag(key)`), else `RCC8` if some transformation offers that (the seed's
/// producer of all relations); otherwise the symbol written without spaces.
pub fn target_tag(
    symbol: &Symbol,
    grounding: &BTreeMap<String, Grounding>,
    has_out_tag: &dyn Fn(&str) -> bool,
) -> TargetTag {
    let key = symbol.key();
    if let Some(g) = grounding.get(&key) {
        return match g {
            Grounding::Tag { tag } => TargetTag::Value(tag.clone()),
            Grounding::Description { description } => TargetTag::Description(description.clone()),
        };
    }
    if symbol.is_spatial() && !has_out_tag(&key) && has_out_tag("RCC8") {
        return TargetTag::Value("RCC8".to_owned());
    }
    TargetTag::Value(key)
}

/// Groundings that name no symbol of the formulas (an invalid grounding, 422).
pub fn unused_groundings<'a>(
    grounding: &'a BTreeMap<String, Grounding>,
    symbols: &BTreeSet<String>,
) -> Vec<&'a str> {
    grounding
        .keys()
        .filter(|k| !symbols.contains(*k))
        .map(String::as_str)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tag value spelled as an IRI and that IRI as a description are two tags: two targets,
    /// two channels (they shared one target, and one group was fed the other's stream).
    #[test]
    fn a_value_spelled_as_an_iri_and_the_iri_name_two_targets() {
        let value = TargetTag::Value("urn:x:Foo".into());
        let description = TargetTag::Description("urn:x:Foo".into());
        assert_eq!(value.label(), "symbol:urn:x:Foo");
        assert_eq!(description.label(), "symbol:<urn:x:Foo>");
        assert_ne!(value.channel(), description.channel());
        // A value written with the brackets is refused, so no value can take the IRI's label.
        let grounding = BTreeMap::from([(
            "p".to_owned(),
            Grounding::Tag {
                tag: "<urn:x:Foo>".into(),
            },
        )]);
        let formulas = ["p".to_owned()];
        let grounded = [ground(0, "p", &Domains::new()).unwrap()];
        match check_groundings(&grounding, &formulas, &grounded) {
            Err(SpecError::Grounding { message, .. }) => {
                assert!(message.contains("description"), "{message}");
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_formula_that_grounds_to_too_many_atoms_is_refused_before_it_is_expanded() {
        let domain = |n: usize| -> Domains {
            [("D".to_owned(), (0..n).map(|i| format!("c{i}")).collect())].into()
        };
        let nested = "forall x in D: forall y in D: forall z in D: always p(x,y,z)";
        // 200³ = 8,000,000 atoms: refused at once (before, this took gigabytes).
        match ground(0, nested, &domain(200)) {
            Err(SpecError::Grounding { message, .. }) => {
                assert!(message.contains("8000000 atoms"), "{message}");
            }
            other => panic!("{:?}", other.map(|g| g.symbols.len())),
        }
        // 21³ = 9,261: taken, and the bound is exactly the number of ground symbols.
        let grounded = ground(0, nested, &domain(21)).unwrap();
        assert_eq!(grounded.symbols.len(), 9_261);
        assert_eq!(ground_atoms(&grounded.formula, &domain(21)), 9_261);
        assert!(ground(0, nested, &domain(22)).is_err());
        // Sums over the parts; an inline set counts its constants.
        let parts = "(forall x in {a,b,c}: p(x)) && q && always r";
        let f = parse(parts).unwrap();
        assert_eq!(ground_atoms(&f, &Domains::new()), 5);
    }

    #[test]
    fn an_unknown_domain_is_named_with_the_groups_way_to_declare_it() {
        match ground(2, "forall x in UAV: altitude(x) > 1", &Domains::new()) {
            Err(SpecError::Grounding {
                index,
                column,
                message,
            }) => {
                assert_eq!((index, column), (2, 13));
                assert!(message.contains("unknown domain 'UAV'"), "{message}");
                assert!(message.contains("\"domains\""), "{message}");
                assert!(message.contains("--domain UAV=a,b"), "{message}");
                assert!(!message.contains("trace header"), "{message}");
            }
            other => panic!("{:?}", other.map(|g| g.symbols.len())),
        }
    }
}
