//! The SDK's errors.

/// A name that is not a valid key expression where one is needed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum KeyError {
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

impl From<zenoh::Error> for CuError {
    fn from(e: zenoh::Error) -> Self {
        Self::Zenoh(e.to_string())
    }
}
