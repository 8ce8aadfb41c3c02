//! Standard 3DGS PLY import/export (binary little endian, one `vertex` element with float
//! properties `x y z nx ny nz f_dc_0..2 opacity scale_0..2 rot_0..3`), so maps open in common
//! splat viewers. Values are stored raw (f_dc, opacity logit, log-scale, unnormalised
//! quaternion), exactly the [`Gaussians`] parameters, so an `f32` map round-trips bit-exactly.
//! Extra vertex properties (e.g. `f_rest_*`) are skipped on import; flags are not stored.

use crate::SplatError;
use crate::gaussians::Gaussians;
use crate::real::Real;
use std::path::Path;

/// Vertex properties written, in order.
const WRITTEN: [&str; 17] = [
    "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
    "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
];

/// Properties an import needs.
const REQUIRED: [&str; 14] = [
    "x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
    "rot_0", "rot_1", "rot_2", "rot_3",
];

/// Serialises the Gaussians to PLY bytes.
pub fn to_ply_bytes<T: Real>(g: &Gaussians<T>) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\n",
        g.len()
    )
    .into_bytes();
    for name in WRITTEN {
        out.extend_from_slice(format!("property float {name}\n").as_bytes());
    }
    out.extend_from_slice(b"end_header\n");
    out.reserve(g.len() * WRITTEN.len() * 4);
    for i in 0..g.len() {
        let (m, c, q, s) = (g.means[i], g.sh_dc[i], g.rotations[i], g.log_scales[i]);
        let row = [
            m[0],
            m[1],
            m[2],
            T::zero(),
            T::zero(),
            T::zero(),
            c[0],
            c[1],
            c[2],
            g.opacity_logits[i],
            s[0],
            s[1],
            s[2],
            q[0],
            q[1],
            q[2],
            q[3],
        ];
        for v in row {
            out.extend_from_slice(&v.to_f32().to_le_bytes());
        }
    }
    out
}

/// Writes the Gaussians to a PLY file.
pub fn write_ply<T: Real>(path: &Path, g: &Gaussians<T>) -> Result<(), SplatError> {
    std::fs::write(path, to_ply_bytes(g)).map_err(|source| SplatError::Io {
        path: path.display().to_string(),
        source,
    })
}

/// Reads Gaussians from a PLY file.
pub fn read_ply<T: Real>(path: &Path) -> Result<Gaussians<T>, SplatError> {
    let bytes = std::fs::read(path).map_err(|source| SplatError::Io {
        path: path.display().to_string(),
        source,
    })?;
    from_ply_bytes(&bytes, &path.display().to_string())
}

/// Byte size of a PLY scalar type, `None` if unknown.
fn type_size(ty: &str) -> Option<usize> {
    Some(match ty {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "int" | "uint" | "int32" | "uint32" | "float" | "float32" => 4,
        "double" | "float64" => 8,
        _ => return None,
    })
}

/// Parses PLY bytes; `origin` names the source in errors.
pub fn from_ply_bytes<T: Real>(bytes: &[u8], origin: &str) -> Result<Gaussians<T>, SplatError> {
    let err = |message: String| SplatError::Ply {
        path: origin.to_string(),
        message,
    };
    let marker = b"end_header\n";
    let header_end = bytes
        .windows(marker.len())
        .position(|w| w == marker)
        .ok_or_else(|| err("no `end_header` line: not a PLY file or truncated header".into()))?;
    let header = std::str::from_utf8(&bytes[..header_end])
        .map_err(|_| err("header is not ASCII text".into()))?;
    let mut lines = header.lines().enumerate();
    if lines.next().map(|(_, l)| l.trim()) != Some("ply") {
        return Err(err("first line is not `ply`".into()));
    }
    let mut format_ok = false;
    let mut vertex_count: Option<usize> = None;
    let mut in_vertex = false;
    let mut seen_element = false;
    // (name, offset, type) of each vertex property.
    let mut props: Vec<(String, usize, String)> = Vec::new();
    let mut stride = 0usize;
    for (no, line) in lines {
        let line_no = no + 1;
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", fmt, _version] => {
                if *fmt != "binary_little_endian" {
                    return Err(err(format!(
                        "line {line_no}: format `{fmt}` unsupported (need binary_little_endian)"
                    )));
                }
                format_ok = true;
            }
            ["element", name, count] => {
                if *name == "vertex" {
                    if seen_element {
                        return Err(err(format!(
                            "line {line_no}: `vertex` must be the first element"
                        )));
                    }
                    let n = count
                        .parse()
                        .map_err(|_| err(format!("line {line_no}: bad vertex count `{count}`")))?;
                    vertex_count = Some(n);
                    in_vertex = true;
                } else {
                    in_vertex = false;
                }
                seen_element = true;
            }
            ["property", "list", ..] if in_vertex => {
                return Err(err(format!(
                    "line {line_no}: list properties in `vertex` are unsupported"
                )));
            }
            ["property", ty, name] if in_vertex => {
                let size = type_size(ty)
                    .ok_or_else(|| err(format!("line {line_no}: unknown type `{ty}`")))?;
                props.push((name.to_string(), stride, ty.to_string()));
                stride += size;
            }
            ["property", ..] => {}
            _ if !seen_element || in_vertex => {
                return Err(err(format!(
                    "line {line_no}: cannot parse header line `{line}`"
                )));
            }
            _ => {}
        }
    }
    if !format_ok {
        return Err(err("missing `format` line".into()));
    }
    let n = vertex_count.ok_or_else(|| err("no `element vertex` line".into()))?;
    let mut columns = Vec::with_capacity(REQUIRED.len());
    for name in REQUIRED {
        let (_, offset, ty) = props
            .iter()
            .find(|(p, _, _)| p == name)
            .ok_or_else(|| err(format!("vertex property `{name}` is missing")))?;
        if !matches!(ty.as_str(), "float" | "float32" | "double" | "float64") {
            return Err(err(format!(
                "vertex property `{name}` has type `{ty}`, expected float"
            )));
        }
        columns.push((*offset, type_size(ty).unwrap_or(4) == 8));
    }
    let data = &bytes[header_end + marker.len()..];
    let needed = n
        .checked_mul(stride)
        .ok_or_else(|| err(format!("vertex count {n} is too large")))?;
    if data.len() < needed {
        return Err(err(format!(
            "truncated data: {n} vertices of {stride} bytes need {needed} bytes, file has {}",
            data.len()
        )));
    }
    let mut g = Gaussians::<T>::new();
    g.means.reserve(n);
    for i in 0..n {
        let row = &data[i * stride..(i + 1) * stride];
        let v: Vec<T> = columns
            .iter()
            .map(|&(off, is_f64)| {
                if is_f64 {
                    let mut b = [0u8; 8];
                    b.copy_from_slice(&row[off..off + 8]);
                    T::of(f64::from_le_bytes(b))
                } else {
                    let mut b = [0u8; 4];
                    b.copy_from_slice(&row[off..off + 4]);
                    T::of_f32(f32::from_le_bytes(b))
                }
            })
            .collect();
        g.means.push([v[0], v[1], v[2]]);
        g.sh_dc.push([v[3], v[4], v[5]]);
        g.opacity_logits.push(v[6]);
        g.log_scales.push([v[7], v[8], v[9]]);
        g.rotations.push([v[10], v[11], v[12], v[13]]);
        g.flags.push(0);
    }
    Ok(g)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn random_map(n: usize) -> Gaussians<f32> {
        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let mut g = Gaussians::new();
        for _ in 0..n {
            g.means.push([0; 3].map(|_| r.random_range(-5.0..5.0)));
            g.sh_dc.push([0; 3].map(|_| r.random_range(-2.0..2.0)));
            g.rotations.push([0; 4].map(|_| r.random_range(-1.0..1.0)));
            g.opacity_logits.push(r.random_range(-6.0..6.0));
            g.log_scales.push([0; 3].map(|_| r.random_range(-7.0..0.0)));
            g.flags.push(0);
        }
        g
    }

    #[test]
    fn round_trip_is_bit_exact() {
        let g = random_map(257);
        let bytes = to_ply_bytes(&g);
        let back: Gaussians<f32> = from_ply_bytes(&bytes, "mem").unwrap();
        assert_eq!(back, g);
        assert_eq!(to_ply_bytes(&back), bytes);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("map.ply");
        write_ply(&path, &g).unwrap();
        let from_file: Gaussians<f32> = read_ply(&path).unwrap();
        assert_eq!(from_file, g);
        // Header layout a viewer expects, and 17 floats per vertex.
        let text = String::from_utf8_lossy(&bytes[..300]);
        assert!(text.starts_with(
            "ply\nformat binary_little_endian 1.0\nelement vertex 257\nproperty float x\n"
        ));
        let header_len = bytes
            .windows(11)
            .position(|w| w == b"end_header\n")
            .unwrap()
            + 11;
        assert_eq!(bytes.len() - header_len, 257 * 17 * 4);
    }

    #[test]
    fn reads_extra_properties_and_doubles() {
        // A hand-written file: one vertex with an extra f_rest_0 and x as double.
        let mut bytes = b"ply\nformat binary_little_endian 1.0\ncomment test\nelement vertex 1\nproperty double x\n".to_vec();
        for name in [
            "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "f_rest_0", "opacity", "scale_0", "scale_1",
            "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
        ] {
            bytes.extend_from_slice(format!("property float {name}\n").as_bytes());
        }
        bytes.extend_from_slice(b"end_header\n");
        bytes.extend_from_slice(&1.5f64.to_le_bytes());
        for v in 0..14 {
            bytes.extend_from_slice(&(v as f32).to_le_bytes());
        }
        let g: Gaussians<f32> = from_ply_bytes(&bytes, "mem").unwrap();
        assert_eq!(g.means[0], [1.5, 0.0, 1.0]);
        assert_eq!(g.sh_dc[0], [2.0, 3.0, 4.0]);
        assert_eq!(g.opacity_logits[0], 6.0);
        assert_eq!(g.log_scales[0], [7.0, 8.0, 9.0]);
        assert_eq!(g.rotations[0], [10.0, 11.0, 12.0, 13.0]);
    }

    fn error_of(bytes: &[u8]) -> String {
        match from_ply_bytes::<f32>(bytes, "bad.ply") {
            Err(e) => e.to_string(),
            Ok(_) => panic!("malformed PLY accepted"),
        }
    }

    #[test]
    fn malformed_files_give_clear_errors() {
        let good = to_ply_bytes(&random_map(3));
        let truncated = error_of(&good[..good.len() - 5]);
        assert!(
            truncated.contains("bad.ply") && truncated.contains("truncated"),
            "{truncated}"
        );
        assert!(error_of(b"hello world").contains("end_header"));
        assert!(error_of(b"plx\nformat binary_little_endian 1.0\nend_header\n").contains("`ply`"));
        let ascii = String::from_utf8_lossy(&good).replace("binary_little_endian", "ascii");
        assert!(error_of(ascii.as_bytes()).contains("unsupported"));
        let missing = String::from_utf8_lossy(&good[..200]).replace("property float rot_3\n", "");
        let missing = error_of(&missing.into_bytes()[..]);
        assert!(
            missing.contains("rot_3") || missing.contains("end_header"),
            "{missing}"
        );
        let header = "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nend_header\n";
        assert!(error_of(header.as_bytes()).contains("`y` is missing"));
        let bad_count = "ply\nformat binary_little_endian 1.0\nelement vertex many\nend_header\n";
        assert!(error_of(bad_count.as_bytes()).contains("bad vertex count"));
        let int_x =
            String::from_utf8_lossy(&good).replacen("property float x", "property int x", 1);
        assert!(error_of(int_x.as_bytes()).contains("expected float"));
    }
}
