//! What can go wrong between an operator and its ports.

use activemap_schemas::SchemaError;

/// An error of the operator API: a port used wrongly, a payload that does not decode or encode,
/// or the sink behind the context (the transport, a replay, a test harness) failing.
#[derive(Debug, thiserror::Error)]
pub enum OperatorError {
    /// The operator sent on a port its node does not declare.
    #[error("node `{node}` has no output `{port}`")]
    UnknownOutput {
        /// Node id.
        node: String,
        /// Port name.
        port: String,
    },
    /// An input the node does not declare (a harness fed a port the operator has not).
    #[error("node `{node}` has no input `{port}`")]
    UnknownInput {
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
    /// The sink behind the context failed (a transport, a replay's callback); its own message.
    #[error(transparent)]
    Sink(Box<dyn std::error::Error + Send + Sync>),
    /// The operator's code that fills a loaned buffer failed.
    #[error("operator failed: {0}")]
    Fill(String),
}

impl OperatorError {
    /// Wraps the error of a sink (keeps its message and its source chain).
    pub fn sink(error: impl std::error::Error + Send + Sync + 'static) -> Self {
        Self::Sink(Box::new(error))
    }
}
