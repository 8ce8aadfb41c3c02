//! Errors of the runtime library.

use activemap_schemas::SchemaError;

/// Everything that can go wrong while running a node or a flow.
#[derive(Debug, thiserror::Error)]
pub enum RuntimeError {
    /// The dataflow file is invalid.
    #[error("{0}")]
    Invalid(#[from] crate::dataflow::Diagnostics),
    /// A node id that the dataflow does not declare.
    #[error("node `{0}` is not in the dataflow")]
    UnknownNode(String),
    /// The operator sent on a port its node does not declare.
    #[error("node `{node}` has no output `{port}`")]
    UnknownOutput {
        /// Node id.
        node: String,
        /// Port name.
        port: String,
    },
    /// A port was used with another message type than it carries.
    #[error("port `{port}` carries {declared}, not {used}")]
    WrongType {
        /// Port name.
        port: String,
        /// Declared kind.
        declared: &'static str,
        /// Kind used.
        used: &'static str,
    },
    /// A received payload did not decode.
    #[error("input `{port}`: {source}")]
    Decode {
        /// Port name.
        port: String,
        /// Schema error.
        source: SchemaError,
    },
    /// A message could not be encoded.
    #[error("output `{port}`: {source}")]
    Encode {
        /// Port name.
        port: String,
        /// Schema error.
        source: SchemaError,
    },
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
