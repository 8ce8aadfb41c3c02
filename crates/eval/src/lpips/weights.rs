//! Reading the LPIPS AlexNet weights from the safetensors file that
//! `tools/lpips/fetch_weights.py` writes, with the `safetensors` crate (the format's reference
//! implementation, which checks the header, the offsets and the sizes).

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
        let file = safetensors::SafeTensors::deserialize(bytes)
            .map_err(|e| invalid(path, format!("not a safetensors file: {e}")))?;
        let mut tensors = HashMap::new();
        for (name, view) in file.tensors() {
            if view.dtype() != safetensors::Dtype::F32 {
                return Err(invalid(
                    path,
                    format!("tensor `{name}`: dtype {:?}, expected F32", view.dtype()),
                ));
            }
            let values = view
                .data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            tensors.insert(name, (view.shape().to_vec(), values));
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
/// A safetensors byte string written by the `safetensors` crate itself.
pub(crate) fn encode_safetensors(entries: &[(&str, Vec<usize>, Vec<f32>)]) -> Vec<u8> {
    let bytes: Vec<Vec<u8>> = entries
        .iter()
        .map(|(_, _, values)| values.iter().flat_map(|v| v.to_le_bytes()).collect())
        .collect();
    let views = entries.iter().zip(&bytes).map(|((name, shape, _), data)| {
        let view =
            safetensors::tensor::TensorView::new(safetensors::Dtype::F32, shape.clone(), data)
                .unwrap();
        ((*name).to_string(), view)
    });
    safetensors::serialize(views, None).unwrap()
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
        let refused = |bytes: &[u8]| TensorFile::parse(p, bytes).unwrap_err().to_string();
        let e = refused(&[1, 2]);
        assert!(
            e.contains("bad.st") && e.contains("not a safetensors file"),
            "{e}"
        );
        let mut huge = u64::MAX.to_le_bytes().to_vec();
        huge.extend_from_slice(b"{}");
        assert!(refused(&huge).contains("not a safetensors file"));
        let mut bytes = encode_safetensors(&[("a", vec![3], vec![1.0, 2.0, 3.0])]);
        bytes.truncate(bytes.len() - 4);
        assert!(refused(&bytes).contains("not a safetensors file"));
        // Another dtype than F32.
        let data = [0u8; 6];
        let view =
            safetensors::tensor::TensorView::new(safetensors::Dtype::F16, vec![3], &data).unwrap();
        let f16 = safetensors::serialize([("h", view)], None).unwrap();
        let e = refused(&f16);
        assert!(e.contains("`h`") && e.contains("F32"), "{e}");
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
