//! Errors of the runtime library.

/// Everything that can go wrong while running a node or a flow.
#[derive(Debug, thiserror::Error)]
pub enum RuntimeError {
    /// The dataflow file is invalid.
    #[error("{0}")]
    Invalid(#[from] crate::dataflow::Diagnostics),
    /// A node id that the dataflow does not declare.
    #[error("node `{0}` is not in the dataflow")]
    UnknownNode(String),
    /// An operator used a port wrongly, or a payload did not decode or encode.
    #[error(transparent)]
    Port(#[from] activemap_operator::OperatorError),
    /// The operator's config does not deserialise.
    #[error("bad config for node `{node}`: {message}")]
    Config {
        /// Node id.
        node: String,
        /// Deserialiser message.
        message: String,
    },
    /// The operator returned an error.
    #[error("operator failed: {0}")]
    Operator(String),
    /// A transport (iceoryx2, Zenoh) failed.
    #[error("transport: {0}")]
    Transport(String),
    /// A file of the run could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// File.
        path: String,
        /// OS error.
        source: std::io::Error,
    },
    /// Anything else, with context.
    #[error("{0}")]
    Other(String),
}

impl RuntimeError {
    /// Wrap an I/O error with the path it concerns.
    pub fn io(path: impl AsRef<std::path::Path>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.as_ref().display().to_string(),
            source,
        }
    }
}
