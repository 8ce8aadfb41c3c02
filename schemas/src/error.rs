//! Decode errors shared by every message type.

/// Why a payload could not be decoded or encoded.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum SchemaError {
    /// The payload is shorter than its header or its declared slices.
    #[error("{what}: payload truncated: need {needed} bytes, got {got}")]
    Truncated {
        /// Message type being decoded.
        what: &'static str,
        /// Bytes the header promises.
        needed: usize,
        /// Bytes actually present.
        got: usize,
    },
    /// The payload was written with another schema version of this type.
    #[error("{what}: schema version mismatch: payload has v{found}, this build reads v{expected}")]
    VersionMismatch {
        /// Message type being decoded.
        what: &'static str,
        /// Version this build understands.
        expected: u32,
        /// Version found in the payload.
        found: u32,
    },
    /// The payload does not start with this type's magic number (wrong topic or garbage).
    #[error("{what}: bad magic 0x{found:08x} (expected 0x{expected:08x}): not a {what} payload")]
    BadMagic {
        /// Message type being decoded.
        what: &'static str,
        /// Magic this type uses.
        expected: u32,
        /// Magic found.
        found: u32,
    },
    /// Header fields are inconsistent (sizes that overflow, lengths that do not match).
    #[error("{what}: invalid header: {reason}")]
    InvalidHeader {
        /// Message type being decoded.
        what: &'static str,
        /// What is inconsistent.
        reason: String,
    },
    /// A destination buffer for in-place writing has the wrong size or alignment.
    #[error("{what}: buffer unusable: {reason}")]
    Buffer {
        /// Message type being written.
        what: &'static str,
        /// What is wrong with the buffer.
        reason: String,
    },
    /// The postcard body of a small message is malformed.
    #[error("{what}: malformed body: {reason}")]
    Malformed {
        /// Message type being decoded.
        what: &'static str,
        /// The decoder's message.
        reason: String,
    },
}
