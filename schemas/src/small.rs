//! Wire format of small messages: a 2-byte little-endian schema version, then the postcard body.

use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::SchemaError;

/// A small serde message with a type name and a schema version, encoded as
/// `version (u16 LE) ++ postcard(body)`. Bump `VERSION` whenever the struct changes.
pub trait SmallMessage: Serialize + DeserializeOwned {
    /// Type name, as used in dataflow files and recordings.
    const TYPE_NAME: &'static str;
    /// Schema version written into every payload.
    const VERSION: u16;

    /// Encode to bytes. Postcard serialisation of these plain structs cannot fail except on
    /// allocation failure, which aborts anyway.
    fn encode(&self) -> Vec<u8> {
        let out = Self::VERSION.to_le_bytes().to_vec();
        postcard::to_extend(self, out).expect("postcard encoding into a Vec cannot fail")
    }

    /// Decode bytes, checking the version and that the whole payload was consumed.
    fn decode(bytes: &[u8]) -> Result<Self, SchemaError> {
        let what = Self::TYPE_NAME;
        if bytes.len() < 2 {
            return Err(SchemaError::Truncated {
                what,
                needed: 2,
                got: bytes.len(),
            });
        }
        let found = u16::from_le_bytes([bytes[0], bytes[1]]);
        if found != Self::VERSION {
            return Err(SchemaError::VersionMismatch {
                what,
                expected: Self::VERSION.into(),
                found: found.into(),
            });
        }
        let (value, rest) =
            postcard::take_from_bytes::<Self>(&bytes[2..]).map_err(|e| SchemaError::Malformed {
                what,
                reason: e.to_string(),
            })?;
        if !rest.is_empty() {
            return Err(SchemaError::Malformed {
                what,
                reason: format!("{} trailing bytes after the message", rest.len()),
            });
        }
        Ok(value)
    }
}
