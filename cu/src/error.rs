//! The SDK's errors.

/// A name that is not a valid key expression where one is needed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum KeyError {
    /// Not an executor instance's id ([`crate::keys::InstanceId`]).
    #[error("{0:?} is not an executor instance (<start, 13 digits>-<hexadecimal Zenoh id>)")]
    Instance(String),
    /// The name is empty.
    #[error("the {0} is empty")]
    Empty(&'static str),
    /// A '/'-separated chunk is empty (`a//b`, a trailing '/').
    #[error("the {what} {name:?} has an empty chunk ('//' or a '/' at an end)")]
    EmptyChunk {
        /// What the name names.
        what: &'static str,
        /// The name.
        name: String,
    },
    /// A chunk holds a character Zenoh reserves.
    #[error("the {what} {name:?} contains {character:?}, which key expressions reserve")]
    Forbidden {
        /// What the name names.
        what: &'static str,
        /// The name.
        name: String,
        /// The character.
        character: char,
    },
    /// A chunk starts with '@' (hermetic chunks are DyKnow's control keys).
    #[error("the {what} {name:?} has a chunk starting with '@', which is reserved")]
    Hermetic {
        /// What the name names.
        what: &'static str,
        /// The name.
        name: String,
    },
    /// A single-chunk name holds a '/'.
    #[error("the {what} {name:?} may not contain '/'")]
    Slash {
        /// What the name names.
        what: &'static str,
        /// The name.
        name: String,
    },
}

/// Why a CU could not be created, rebound or run.
#[derive(Debug, thiserror::Error)]
pub enum CuError {
    /// A name or channel is not a key expression.
    #[error(transparent)]
    Key(#[from] KeyError),
    /// The transformation has no such port.
    #[error("{cu} has no {direction} port {port:?}")]
    UnknownPort {
        /// The CU.
        cu: String,
        /// `in` or `out`.
        direction: &'static str,
        /// The port.
        port: String,
    },
    /// A parameter is missing or has the wrong type.
    #[error("parameter {name:?}: {why}")]
    Parameter {
        /// The parameter.
        name: String,
        /// What is wrong.
        why: String,
    },
    /// The transformation refused to start or failed.
    #[error("{0}")]
    Failed(String),
    /// Zenoh refused a declaration.
    #[error("zenoh: {0}")]
    Zenoh(String),
    /// The CU has crashed or stopped.
    #[error("{0} is not running")]
    NotRunning(String),
}

impl CuError {
    /// A failure with a message.
    pub fn failed(message: impl Into<String>) -> Self {
        Self::Failed(message.into())
    }
}

/// A Zenoh error's message for users: Zenoh appends the source location of each error it
/// wraps (` at /…/registry/src/…/endpoint.rs:615.`), which says nothing to a user and leaks the
/// build machine's paths; they are left out.
pub fn zenoh_message(error: &dyn std::fmt::Display) -> String {
    without_source_locations(&error.to_string())
}

/// `text` without ` at PATH.rs:LINE` (and the `.` after it).
fn without_source_locations(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(i) = rest.find(" at ") {
        let after = &rest[i + " at ".len()..];
        let end = after
            .find(|c: char| c.is_whitespace() || c == '"')
            .unwrap_or(after.len());
        let location = after[..end].trim_end_matches('.');
        let is_location = location.rsplit_once(':').is_some_and(|(path, line)| {
            path.ends_with(".rs") && !line.is_empty() && line.bytes().all(|b| b.is_ascii_digit())
        });
        if is_location {
            out.push_str(&rest[..i]);
            rest = &after[end..];
        } else {
            out.push_str(&rest[..i + " at ".len()]);
            rest = after;
        }
    }
    out.push_str(rest);
    out.truncate(out.trim_end().len());
    out
}

impl From<zenoh::Error> for CuError {
    fn from(e: zenoh::Error) -> Self {
        Self::Zenoh(zenoh_message(&e))
    }
}

#[cfg(test)]
mod location_tests {
    use super::without_source_locations;

    #[test]
    fn source_locations_are_left_out_and_nothing_else() {
        assert_eq!(
            without_source_locations(
                "Json5Err(Message { msg: \"Endpoints must be of the form x: bogus at /root/.cargo/registry/src/a/zenoh-protocol/src/core/endpoint.rs:615.\", location: Some(Location { line: 1 }) }) at /root/.cargo/registry/src/b/config.rs:86."
            ),
            "Json5Err(Message { msg: \"Endpoints must be of the form x: bogus\", location: Some(Location { line: 1 }) })"
        );
        for kept in [
            "cannot connect at once",
            "look at main.rs",
            "at /a/b.rs:12x.",
            "no location here",
            "",
        ] {
            assert_eq!(without_source_locations(kept), kept);
        }
        assert_eq!(
            without_source_locations("refused at /x/y.rs:3. (is the router running?)"),
            "refused (is the router running?)"
        );
        assert_eq!(
            without_source_locations("refused!  at /x/y.rs:3."),
            "refused!"
        );
    }
}
