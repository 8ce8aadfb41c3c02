//! Mutual TLS for daemons, their clients and the runs they start (issue 18).
//!
//! Every party holds a certificate signed by one certificate authority (CA) and its private key;
//! a Zenoh link is accepted only when both sides present a certificate of that CA (Zenoh's
//! `enable_mtls`), and a connecting side also checks that the certificate it is shown names the
//! host it dialled. The files are PEM and are given by path (`--tls-ca`, `--tls-cert`,
//! `--tls-key`); only the paths ever appear in logs, `run.json` or `list` output, never the
//! keys.

use std::path::{Path, PathBuf};

use crate::RuntimeError;

/// The PEM files of one party's mutual-TLS identity.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TlsFiles {
    /// The CA certificate that signed every party's certificate.
    pub ca: PathBuf,
    /// This party's certificate (its names: the addresses others dial it on).
    pub cert: PathBuf,
    /// This party's private key.
    pub key: PathBuf,
}

impl TlsFiles {
    /// Absolute paths (the files are read by Zenoh, possibly in node processes started in
    /// another working directory), each checked to be a readable PEM file of the expected kind.
    /// The error names the file and what is wrong, never its content.
    pub fn checked(&self) -> Result<Self, RuntimeError> {
        let check = |path: &Path, role: &str, markers: &[&str]| -> Result<PathBuf, RuntimeError> {
            let abs = std::path::absolute(path).map_err(|e| RuntimeError::io(path, e))?;
            let text = std::fs::read(&abs)
                .map_err(|e| RuntimeError::Other(format!("TLS {role} {}: {e}", abs.display())))?;
            let text = String::from_utf8_lossy(&text);
            if !markers.iter().any(|m| text.contains(m)) {
                return Err(RuntimeError::Other(format!(
                    "TLS {role} {}: not a PEM file with {}",
                    abs.display(),
                    markers.join(" or ")
                )));
            }
            Ok(abs)
        };
        let cert_markers = ["-----BEGIN CERTIFICATE-----"];
        Ok(Self {
            ca: check(&self.ca, "CA certificate", &cert_markers)?,
            cert: check(&self.cert, "certificate", &cert_markers)?,
            key: check(
                &self.key,
                "private key",
                &[
                    "-----BEGIN PRIVATE KEY-----",
                    "-----BEGIN RSA PRIVATE KEY-----",
                    "-----BEGIN EC PRIVATE KEY-----",
                ],
            )?,
        })
    }

    /// Zenoh's `transport/link/tls` settings for this identity: the same certificate and key
    /// when listening and when connecting, client certificates required (`enable_mtls`), and
    /// the dialled name checked on connect.
    pub fn zenoh_config(&self) -> serde_json::Value {
        let path = |p: &Path| serde_json::Value::String(p.display().to_string());
        serde_json::json!({
            "root_ca_certificate": path(&self.ca),
            "listen_certificate": path(&self.cert),
            "listen_private_key": path(&self.key),
            "connect_certificate": path(&self.cert),
            "connect_private_key": path(&self.key),
            "enable_mtls": true,
            "verify_name_on_connect": true,
        })
    }
}

/// The TLS files given on the command line: all three or none.
pub fn tls_from_args(
    ca: Option<PathBuf>,
    cert: Option<PathBuf>,
    key: Option<PathBuf>,
) -> Result<Option<TlsFiles>, RuntimeError> {
    match (ca, cert, key) {
        (None, None, None) => Ok(None),
        (Some(ca), Some(cert), Some(key)) => Ok(Some(TlsFiles { ca, cert, key }.checked()?)),
        _ => Err(RuntimeError::Other(
            "mutual TLS needs all three of --tls-ca, --tls-cert and --tls-key".into(),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn files_are_checked_by_kind_and_named_in_errors_without_their_content() {
        let dir = tempfile::tempdir().unwrap();
        let ca = dir.path().join("ca.pem");
        let cert = dir.path().join("a.pem");
        let key = dir.path().join("a.key");
        std::fs::write(
            &ca,
            "-----BEGIN CERTIFICATE-----\nMIIB\n-----END CERTIFICATE-----\n",
        )
        .unwrap();
        std::fs::write(
            &cert,
            "-----BEGIN CERTIFICATE-----\nMIIC\n-----END CERTIFICATE-----\n",
        )
        .unwrap();
        std::fs::write(
            &key,
            "-----BEGIN PRIVATE KEY-----\nSECRETSTUFF\n-----END PRIVATE KEY-----\n",
        )
        .unwrap();
        let files = tls_from_args(Some(ca.clone()), Some(cert.clone()), Some(key.clone()))
            .unwrap()
            .unwrap();
        let config = files.zenoh_config();
        assert_eq!(config["enable_mtls"], true);
        assert_eq!(config["listen_private_key"], key.display().to_string());
        assert!(!config.to_string().contains("SECRETSTUFF"));
        // The key given as the certificate: refused, naming the file, not showing the key.
        let err = tls_from_args(Some(ca.clone()), Some(key.clone()), Some(key.clone()))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("a.key") && err.contains("certificate"),
            "{err}"
        );
        assert!(!err.contains("SECRETSTUFF"), "{err}");
        let err = tls_from_args(Some(ca.clone()), None, Some(key))
            .unwrap_err()
            .to_string();
        assert!(err.contains("all three"), "{err}");
        let err = tls_from_args(
            Some(dir.path().join("missing.pem")),
            Some(cert.clone()),
            Some(cert),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("missing.pem"), "{err}");
        assert_eq!(tls_from_args(None, None, None).unwrap(), None);
    }
}
