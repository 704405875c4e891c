//! Reading sysfs attribute files: one value per file, text, ending in a newline.

use super::MeterError;
use std::path::{Path, PathBuf};

/// The file's text without its trailing newline (and surrounding blanks).
pub(crate) fn read_text(path: &Path) -> Result<String, MeterError> {
    std::fs::read_to_string(path)
        .map(|text| text.trim().to_string())
        .map_err(|source| MeterError::Io {
            path: path.to_path_buf(),
            source,
        })
}

/// A non-negative integer attribute (µW, µJ, mV, mA, mW).
pub(crate) fn read_u64(path: &Path) -> Result<u64, MeterError> {
    let text = read_text(path)?;
    text.parse().map_err(|_| MeterError::Garbage {
        path: path.to_path_buf(),
        text,
        expected: "a whole non-negative number",
    })
}

/// The entries of a directory whose names satisfy `keep`, sorted by name in natural order
/// (`hwmon2` before `hwmon10`). A missing directory has none; other errors are returned.
pub(crate) fn entries(
    dir: &Path,
    keep: impl Fn(&str) -> bool,
) -> Result<Vec<(String, PathBuf)>, std::io::Error> {
    let read = match std::fs::read_dir(dir) {
        Ok(read) => read,
        Err(error) if error.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(error) => return Err(error),
    };
    let mut out = Vec::new();
    for entry in read {
        let entry = entry?;
        let Ok(name) = entry.file_name().into_string() else {
            continue;
        };
        if keep(&name) {
            out.push((name, entry.path()));
        }
    }
    out.sort_by_key(|a| natural_key(&a.0));
    Ok(out)
}

/// Splits a name into its text and its numbers, so names sort by the numbers' values.
fn natural_key(name: &str) -> Vec<(String, u64)> {
    let mut key = Vec::new();
    let mut text = String::new();
    let mut chars = name.chars().peekable();
    while let Some(&c) = chars.peek() {
        if c.is_ascii_digit() {
            let mut digits = String::new();
            while let Some(&d) = chars.peek().filter(|d| d.is_ascii_digit()) {
                digits.push(d);
                chars.next();
            }
            key.push((
                std::mem::take(&mut text),
                digits.parse().unwrap_or(u64::MAX),
            ));
        } else {
            text.push(c);
            chars.next();
        }
    }
    key.push((text, 0));
    key
}

/// `prefix<N>suffix` → `N`.
pub(crate) fn channel_number(name: &str, prefix: &str, suffix: &str) -> Option<u32> {
    let digits = name.strip_prefix(prefix)?.strip_suffix(suffix)?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn natural_order_and_channel_numbers() {
        let mut names = vec!["hwmon10", "hwmon2", "hwmon1", "iio:device0"];
        names.sort_by_key(|n| natural_key(n));
        assert_eq!(names, ["hwmon1", "hwmon2", "hwmon10", "iio:device0"]);
        assert_eq!(
            channel_number("in_power12_input", "in_power", "_input"),
            Some(12)
        );
        assert_eq!(channel_number("in_power_input", "in_power", "_input"), None);
        assert_eq!(
            channel_number("in_powerx_input", "in_power", "_input"),
            None
        );
        assert_eq!(channel_number("power1_label", "power", "_input"), None);
    }
}
