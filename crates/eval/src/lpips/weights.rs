//! Reading the LPIPS AlexNet weights from the safetensors file that
//! `tools/lpips/fetch_weights.py` writes: an 8-byte little-endian header length, a JSON header
//! `{name: {dtype, shape, data_offsets}}`, then the raw little-endian data.

use crate::error::EvalError;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The command that fetches and converts the weights (run from the workspace root).
pub const FETCH_COMMAND: &str = "python3 tools/lpips/fetch_weights.py";

/// Environment variable that overrides the weight file location.
pub const WEIGHTS_ENV: &str = "ACTIVEMAP_LPIPS_WEIGHTS";

/// Where the weights are looked for: `$ACTIVEMAP_LPIPS_WEIGHTS`, else
/// `$HOME/.cache/activemap/lpips_alex.safetensors` (the fetch script's default).
pub fn default_weights_path() -> PathBuf {
    if let Some(p) = std::env::var_os(WEIGHTS_ENV).filter(|p| !p.is_empty()) {
        return PathBuf::from(p);
    }
    let home = std::env::var_os("HOME").map_or_else(|| PathBuf::from("."), PathBuf::from);
    home.join(".cache/activemap/lpips_alex.safetensors")
}

/// The f32 tensors of one safetensors file, by name, with their shapes.
#[derive(Debug)]
pub(crate) struct TensorFile {
    path: PathBuf,
    tensors: HashMap<String, (Vec<usize>, Vec<f32>)>,
}

impl TensorFile {
    /// Reads and parses the whole file.
    pub(crate) fn read(path: &Path) -> Result<Self, EvalError> {
        let bytes = match std::fs::read(path) {
            Ok(b) => b,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(EvalError::LpipsWeightsMissing {
                    path: path.to_path_buf(),
                    fetch_command: FETCH_COMMAND,
                });
            }
            Err(e) => return Err(invalid(path, format!("cannot read: {e}"))),
        };
        Self::parse(path, &bytes)
    }

    /// Parses safetensors bytes; `path` names the source in errors.
    pub(crate) fn parse(path: &Path, bytes: &[u8]) -> Result<Self, EvalError> {
        let Some((len_bytes, rest)) = bytes.split_first_chunk::<8>() else {
            return Err(invalid(
                path,
                "shorter than the 8-byte header length".into(),
            ));
        };
        let header_len = u64::from_le_bytes(*len_bytes);
        let header_len = usize::try_from(header_len)
            .ok()
            .filter(|&n| n <= rest.len())
            .ok_or_else(|| {
                invalid(
                    path,
                    format!(
                        "header length {header_len} exceeds the file ({} bytes)",
                        bytes.len()
                    ),
                )
            })?;
        let (header, data) = rest.split_at(header_len);
        let header: serde_json::Map<String, serde_json::Value> = serde_json::from_slice(header)
            .map_err(|e| invalid(path, format!("header is not a JSON object: {e}")))?;
        let mut tensors = HashMap::new();
        for (name, entry) in header {
            if name == "__metadata__" {
                continue;
            }
            let bad = |what: &str| invalid(path, format!("tensor `{name}`: {what}"));
            let dtype = entry.get("dtype").and_then(|d| d.as_str());
            if dtype != Some("F32") {
                return Err(bad(&format!("dtype {dtype:?}, expected \"F32\"")));
            }
            let numbers = |key: &str| -> Option<Vec<usize>> {
                entry
                    .get(key)?
                    .as_array()?
                    .iter()
                    .map(|v| v.as_u64().and_then(|n| usize::try_from(n).ok()))
                    .collect()
            };
            let shape = numbers("shape").ok_or_else(|| bad("missing or bad `shape`"))?;
            let offsets = numbers("data_offsets")
                .filter(|o| o.len() == 2 && o[0] <= o[1] && o[1] <= data.len())
                .ok_or_else(|| bad("missing `data_offsets` or outside the data"))?;
            let count: usize = shape.iter().product();
            if offsets[1] - offsets[0] != 4 * count {
                return Err(bad(&format!(
                    "shape {shape:?} needs {} bytes, offsets give {}",
                    4 * count,
                    offsets[1] - offsets[0]
                )));
            }
            let values = data[offsets[0]..offsets[1]]
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            tensors.insert(name, (shape, values));
        }
        Ok(Self {
            path: path.to_path_buf(),
            tensors,
        })
    }

    /// Takes tensor `name`, checking that its shape is `shape` and its values are finite.
    pub(crate) fn take(&mut self, name: &str, shape: &[usize]) -> Result<Vec<f32>, EvalError> {
        let (found, values) = self
            .tensors
            .remove(name)
            .ok_or_else(|| invalid(&self.path, format!("tensor `{name}` is missing")))?;
        if found != shape {
            return Err(invalid(
                &self.path,
                format!("tensor `{name}` has shape {found:?}, expected {shape:?}"),
            ));
        }
        if values.iter().any(|v| !v.is_finite()) {
            return Err(invalid(
                &self.path,
                format!("tensor `{name}` holds a non-finite value"),
            ));
        }
        Ok(values)
    }
}

/// An [`EvalError::LpipsWeightsInvalid`] for `path`.
fn invalid(path: &Path, detail: String) -> EvalError {
    EvalError::LpipsWeightsInvalid {
        path: path.to_path_buf(),
        detail,
    }
}

#[cfg(test)]
/// Builds a safetensors byte string by hand (the format is tiny).
pub(crate) fn encode_safetensors(entries: &[(&str, Vec<usize>, Vec<f32>)]) -> Vec<u8> {
    let mut header = serde_json::Map::new();
    let mut data = Vec::new();
    for (name, shape, values) in entries {
        let start = data.len();
        for v in values {
            data.extend_from_slice(&v.to_le_bytes());
        }
        header.insert(
            (*name).to_string(),
            serde_json::json!({"dtype": "F32", "shape": shape, "data_offsets": [start, data.len()]}),
        );
    }
    let header = serde_json::to_vec(&header).unwrap();
    let mut out = (header.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(&header);
    out.extend_from_slice(&data);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_tensors_and_checks_shapes() {
        let bytes = encode_safetensors(&[("a", vec![2, 2], vec![1.0, -2.0, 3.5, 4.0])]);
        let mut file = TensorFile::parse(Path::new("w.st"), &bytes).unwrap();
        let e = TensorFile::parse(Path::new("w.st"), &bytes)
            .unwrap()
            .take("a", &[4])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("w.st") && e.contains("[2, 2]") && e.contains("[4]"),
            "{e}"
        );
        assert_eq!(file.take("a", &[2, 2]).unwrap(), vec![1.0, -2.0, 3.5, 4.0]);
        let e = file.take("b", &[1]).unwrap_err().to_string();
        assert!(e.contains("`b` is missing"), "{e}");
    }

    #[test]
    fn corrupt_files_are_refused() {
        let p = Path::new("bad.st");
        assert!(
            TensorFile::parse(p, &[1, 2])
                .unwrap_err()
                .to_string()
                .contains("8-byte")
        );
        let mut huge = u64::MAX.to_le_bytes().to_vec();
        huge.extend_from_slice(b"{}");
        assert!(
            TensorFile::parse(p, &huge)
                .unwrap_err()
                .to_string()
                .contains("exceeds")
        );
        let mut bytes = encode_safetensors(&[("a", vec![3], vec![1.0, 2.0, 3.0])]);
        bytes.truncate(bytes.len() - 4);
        let e = TensorFile::parse(p, &bytes).unwrap_err().to_string();
        assert!(e.contains("`a`") && e.contains("outside the data"), "{e}");
    }

    #[test]
    fn missing_file_names_the_fetch_command() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("absent.safetensors");
        let e = TensorFile::read(&path).err().unwrap().to_string();
        assert!(
            e.contains("absent.safetensors") && e.contains(FETCH_COMMAND),
            "{e}"
        );
    }
}
